"""Sensor time and pacing of an emulator node (:class:`PacedEmulator`): the epoch, the
wall-clock or /clock pacing of ``step()``, /clock and the duration limit. The emulator
nodes' base, :class:`~mems_sim.ros.node_base.EmulatorNode`, mixes it in; docs/recording.md
describes sensor time.
"""

from __future__ import annotations


class PacedEmulator:
    """Mixin of emulator nodes: sensor time, pacing of ``step()``, /clock and the duration limit.

    The node sets ``self.p`` (with the :data:`~mems_sim.ros.node_base.EMULATOR_SPECS` values), calls
    :meth:`init_emulator` with its sample rate, and implements ``step()`` with
    :meth:`next_frame_size` and :meth:`frame_published`.

    Sensor time: sample k is stamped ``t0_ns + k / fs`` (:func:`~mems_sim.ros.frames.index_to_ns`,
    exact integer arithmetic), ``t0_ns`` being the run's epoch (``stamp_origin``): 0, or the
    graph's time when the node starts publishing (the wall clock; /clock's time when
    use_sim_time is true). The epoch is fixed once, before the first frame, and never moves.

    Pacing (a node that paces itself, :meth:`start`): a timer on the steady clock wakes the
    node every few milliseconds whatever the ROS time does, so the node never waits on a
    clock that does not move and still stops on SIGINT/SIGTERM. Each tick publishes the
    frames whose last sample is due:

    * by default on the wall clock, ``realtime_factor`` simulated seconds per wall-clock
      second, catching up on lag; ``realtime_factor`` may change while the node runs
      (:meth:`repace` continues from the current sample index at the new rate);
    * when use_sim_time is true (set at start or at runtime) and the node does not publish
      /clock itself: on the node's ROS clock, i.e. the /clock it receives, one simulated
      second per second of /clock (``realtime_factor`` does not apply; the clock's source
      sets the pace, e.g. ``mcap_play --clock --rate R``). The pacing is relative: from the
      sample index and /clock time at which it started, so the epochs of the node and of the
      clock source need not agree. Nothing is published before the first /clock message;
      a /clock that goes backwards (a replay that loops) restarts the pacing from there.

    Each tick does at most :data:`TICK_BUDGET_S` of work and continues at the next tick, and
    publishes no frame that :meth:`flow_allows` holds back (the node's consumers are behind:
    the pacing falls behind and catches up once they report progress).

    /clock (``publish_clock`` > 0): the node is the graph's clock source and publishes its
    sensor time (:meth:`sensor_time_ns`) on /clock that many times per wall-clock second while
    it runs, then once more at the end of its data, and stops; it then paces on the wall clock
    even when use_sim_time is true (its own ROS clock follows the /clock it publishes).
    """

    #: Longest time [s] one pacing tick spends publishing frames (then the executor runs).
    TICK_BUDGET_S = 0.2

    def init_emulator(
        self, fs: float, schedule_samples: int | None = None, *, self_paced: bool = False
    ) -> None:
        """Sample rate fs [Hz], stamp origin, sample budget (``duration_s``; 0: unlimited;
        at most ``schedule_samples`` if given), counters and pacing state.

        ``self_paced``: the node paces itself from start (its executable); ``stamp_origin``
        'auto' is then 'wall', else 'zero'.
        """
        from rclpy.clock import Clock, ClockType

        self.fs = fs
        origin = self.p["stamp_origin"]
        if origin == "auto":
            origin = "wall" if self_paced else "zero"
        self.stamp_origin = origin
        #: Epoch [ns]: time of sample 0 (None until fixed, see :meth:`fix_epoch`).
        self.t0_ns: int | None = 0 if origin == "zero" else None
        total = int(round(self.p["duration_s"] * fs)) if self.p["duration_s"] > 0 else None
        if schedule_samples is not None:
            total = schedule_samples if total is None else min(total, schedule_samples)
        self.total_samples = total
        self.next_index = 0
        self.frames_published = 0
        self._timer = None
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._wall_start = None  # monotonic time [s] at which sample _index_start was due
        self._sim_start_ns = None  # /clock time [ns] at which sample _index_start was due
        self._sim_last_ns = 0  # /clock time [ns] at the last tick
        self._index_start = 0
        self._clock_pub = None
        self._next_clock = None  # monotonic time [s] of the next /clock message
        self._clock_done = False
        if self.p["publish_clock"] > 0:
            from rosgraph_msgs.msg import Clock as ClockMsg

            self._clock_pub = self.create_publisher(ClockMsg, "/clock", 10)

    # ------------------------------------------------------------------ sensor time

    def ros_time_active(self) -> bool:
        """True while use_sim_time is true (the node's ROS clock follows /clock)."""
        return bool(self.get_clock().ros_time_is_active)

    def follows_clock(self) -> bool:
        """True when the pacing follows /clock: use_sim_time is true and the node is not the
        clock source itself (``publish_clock`` = 0)."""
        return self.p["publish_clock"] <= 0 and self.ros_time_active()

    def fix_epoch(self, wait_for_clock: bool = False) -> bool:
        """Fix ``t0_ns`` if it is not fixed yet; True once it is.

        'zero': 0; 'wall': the node's ROS clock now (the wall clock, or /clock's time when
        use_sim_time is true). With ``wait_for_clock``, a node under use_sim_time that has not
        received /clock yet leaves the epoch open and returns False.
        """
        if self.t0_ns is not None:
            return True
        now = self.get_clock().now().nanoseconds
        if wait_for_clock and now == 0 and self.ros_time_active():
            return False
        self.t0_ns = int(now)
        return True

    def sensor_time_ns(self) -> int:
        """The node's current time on its sensor timeline [ns] (stamps and /clock).

        Following /clock: the node's ROS clock. Pacing itself on the wall clock: the epoch plus
        the simulated time reached by the pacing (at most the end of the data). Otherwise (its
        owner steps it): the time of the next sample to publish, epoch + next_index / fs.
        """
        from mems_sim.ros.frames import index_to_ns

        if self.follows_clock() and self._timer is not None:
            return self.get_clock().now().nanoseconds
        t0 = self.t0_ns if self.t0_ns is not None else self.get_clock().now().nanoseconds
        done = index_to_ns(self.next_index, self.fs, t0)
        if self._timer is None or self._wall_start is None or self._sim_start_ns is not None:
            return done
        import time

        elapsed = (time.monotonic() - self._wall_start) * self.p["realtime_factor"]
        now = index_to_ns(self._index_start, self.fs, t0) + int(elapsed * 1e9)
        if self.total_samples is not None:
            now = min(now, index_to_ns(self.total_samples, self.fs, t0))
        return max(now, done) if self.finished else now

    def graph_time_ns(self) -> int:
        """Time of the node's diagnostics stamps: its sensor time."""
        return self.sensor_time_ns()

    @property
    def frame_kwargs(self) -> dict:
        """``frame_id`` and ``t0_ns`` of every frame the node publishes."""
        self.fix_epoch()
        return dict(frame_id=self.p["frame_id"], t0_ns=self.t0_ns)

    # ------------------------------------------------------------------ frames

    def next_frame_size(self) -> int:
        """Samples of the next frame: ``frame_size``, fewer at the end, 0 when finished."""
        n = self.p["frame_size"]
        if self.total_samples is not None:
            n = min(n, self.total_samples - self.next_index)
        return max(n, 0)

    def frame_published(self, n: int) -> None:
        """Advance the sample index by the n samples just published."""
        self.next_index += n
        self.frames_published += 1

    @property
    def finished(self) -> bool:
        """True once ``duration_s`` worth of samples has been published."""
        return self.total_samples is not None and self.next_index >= self.total_samples

    # ------------------------------------------------------------------ pacing

    def _timer_period(self) -> float:
        period = self.p["frame_size"] / self.fs / self.p["realtime_factor"]
        return max(min(period, 0.05), 0.001)

    def start(self) -> None:
        """Start publishing, paced by a timer on the steady clock (class docstring)."""
        if self._timer is None:
            self._timer = self.create_timer(
                self._timer_period(), self._on_timer, clock=self._steady
            )

    def repace(self) -> None:
        """After a change of ``realtime_factor``: pace on from the current sample index at
        the new rate (a running timer gets the new period)."""
        import time

        if self._wall_start is not None:
            self._wall_start = time.monotonic()
            self._index_start = self.next_index
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = self.create_timer(
                self._timer_period(), self._on_timer, clock=self._steady
            )

    def _due(self) -> float | None:
        """Samples due by now (None: nothing can be published yet); (re)starts the pacing
        reference when the pacing starts, changes between wall clock and /clock, or /clock
        went backwards."""
        import time

        if self.follows_clock():
            now_ns = self.get_clock().now().nanoseconds
            if now_ns == 0:
                return None  # no /clock received yet
            if self._sim_start_ns is None or now_ns < self._sim_last_ns:
                self._sim_start_ns, self._wall_start = now_ns, None
                self._index_start = self.next_index
            self._sim_last_ns = now_ns
            return self._index_start + (now_ns - self._sim_start_ns) * 1e-9 * self.fs
        now = time.monotonic()
        if self._wall_start is None:
            self._wall_start, self._sim_start_ns = now, None
            self._index_start = self.next_index
        return self._index_start + (now - self._wall_start) * self.p["realtime_factor"] * self.fs

    def _on_timer(self) -> None:
        """Publish every frame whose last sample is due (catches up on lag, within
        :data:`TICK_BUDGET_S` per tick); publish /clock when due."""
        import time

        if not self.finished and self.fix_epoch(wait_for_clock=True):
            due = self._due()
            if due is not None:
                budget = time.monotonic() + self.TICK_BUDGET_S
                while (
                    not self.finished
                    and self.next_index + self.p["frame_size"] <= due
                    and time.monotonic() < budget
                    and self.flow_allows(self.next_index, self.next_frame_size())
                ):
                    self.step()
        self.publish_clock_if_due()

    def flow_allows(self, first: int, n: int) -> bool:
        """True if the frame of samples ``[first, first + n)`` may be published now (flow
        control by the node's consumers; here: always)."""
        return True

    def publish_clock_if_due(self) -> None:
        """Publish the sensor time on /clock when ``publish_clock`` says so (wall-clock
        period; once more at the end of the data, then no more)."""
        if self._clock_pub is None or self._clock_done or self.t0_ns is None:
            return
        import time

        now = time.monotonic()
        if self.finished:
            self._clock_done = True
        elif self._next_clock is not None and now < self._next_clock:
            return
        period = 1.0 / self.p["publish_clock"]
        nxt = now + period if self._next_clock is None else self._next_clock + period
        self._next_clock = max(nxt, now)
        from rosgraph_msgs.msg import Clock as ClockMsg

        msg = ClockMsg()
        msg.clock.sec, msg.clock.nanosec = divmod(int(self.sensor_time_ns()), 1_000_000_000)
        self._clock_pub.publish(msg)
