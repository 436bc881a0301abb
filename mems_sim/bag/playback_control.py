"""Pause, resume and play-next of a replay: the control services of rosbag2's player
(``~/pause``, ``~/resume``, ``~/toggle_paused``, ``~/is_paused``, ``~/play_next``) as
std_srvs/srv/Trigger. Docs: docs/recording.md (``mcap_play``).
"""

from __future__ import annotations

#: The player's control services: name (relative to the node, ``~/``) -> what it does.
#: Names are those of rosbag2's player; the types are std_srvs/srv/Trigger, because
#: rosbag2_interfaces is not distributed as a Python wheel.
CONTROL_SERVICES = {
    "pause": "pause playback (the clock holds); success true",
    "resume": "resume playback; success true",
    "toggle_paused": "pause when playing, resume when paused; message: the new state",
    "is_paused": "success: true when paused; message: paused or playing",
    "play_next": "while paused, publish the next message; success false when playing "
    "or at the end of the bag",
}


class PlaybackControl:
    """Pause, resume and play-next of a replay, as rosbag2's player offers them.

    The services (:data:`CONTROL_SERVICES`, on the player's node, ``~/NAME``) are
    std_srvs/srv/Trigger; rosbag2_interfaces' types map onto it so: Pause, Resume,
    TogglePaused -> Trigger (success true; message the state afterwards), IsPaused ->
    Trigger (success = paused), PlayNext -> Trigger (success as PlayNext's: true when the
    player is paused and a message is left; the message is published right after the
    reply). While paused the player publishes nothing and /clock holds.

    :param paused: start paused (``--start-paused``).
    """

    def __init__(self, paused: bool = False):
        self.paused = bool(paused)
        self.next_requests = 0  # play_next calls not served yet
        self.finished = False  # the replay reached its end
        self.services: list = []

    def pause(self) -> None:
        self.paused = True

    def resume(self) -> None:
        self.paused = False
        self.next_requests = 0

    def request_next(self) -> tuple[bool, str]:
        """Ask for the next message (paused only); ``(success, message)``."""
        if not self.paused:
            return False, "not paused"
        if self.finished:
            return False, "end of the bag"
        self.next_requests += 1
        return True, "publishing the next message"

    def take_next(self) -> bool:
        """True (once per request) when the player should publish one message now."""
        if self.next_requests > 0:
            self.next_requests -= 1
            return True
        return False

    def state(self) -> str:
        return "paused" if self.paused else "playing"

    def create_services(self, node) -> None:
        """Offer :data:`CONTROL_SERVICES` on ``node`` (std_srvs must be installed)."""
        from std_srvs.srv import Trigger

        def handler(action):
            def call(request, response):
                response.success, response.message = action()
                return response

            return call

        def set_paused(paused: bool):
            def action():
                self.pause() if paused else self.resume()
                return True, self.state()

            return action

        def toggle():
            self.resume() if self.paused else self.pause()
            return True, self.state()

        actions = {
            "pause": set_paused(True),
            "resume": set_paused(False),
            "toggle_paused": toggle,
            "is_paused": lambda: (self.paused, self.state()),
            "play_next": self.request_next,
        }
        for name in CONTROL_SERVICES:
            self.services.append(node.create_service(Trigger, f"~/{name}", handler(actions[name])))


def control_available() -> str | None:
    """None when the control services can be offered, else why not (one line)."""
    try:
        import std_srvs.srv  # noqa: F401  (import check: the services need its Trigger type)
    except ImportError:
        return "the std_srvs interfaces (std_srvs/srv/Trigger) are not installed"
    return None
