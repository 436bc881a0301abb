"""Monte Carlo campaigns of a scenario on Dask distributed: ``run_campaign``.

``run_campaign NAME --seeds A-B [--device-seeds A-B] [--temperatures T1,T2,...]
[--set NODE.PARAM=VALUE ...] [--grid NODE.PARAM=V1,V2,...] [--draw NODE.PARAM=LO:HI
--draws N] [--duration S] [--workers N | --scheduler tcp://HOST:PORT] --out DIR [--json]``

A campaign is the product of noise seeds x device seeds x temperatures x parameter
points (the grid's product, times ``--draws`` uniform random draws of the ``--draw``
ranges). Each run is one ``run_scenario NAME ... --json`` in a process of its own, on a
ROS domain of its own (``run_scenario`` leases a free one of 1..101 without the
Makefile's, so concurrent runs never share one: the campaign removes ``ROS_DOMAIN_ID`` from
the run's environment), with localhost-only discovery. Runs are Dask tasks
(https://distributed.dask.org): ``--workers N`` starts a local cluster of N workers
(one thread each, in this process: each only waits on its run's process; default: the
machine's cores), talking over Dask's in-process transport (no socket at all);
``--scheduler tcp://HOST:PORT`` uses an existing cluster (its workers need this package
installed); ``--workers 0`` runs serially in this process without Dask.

``DIR`` holds:

* ``runs/<run id>.json`` -- one file per finished run (written atomically when the run
  ends): its spec, status (``ok``, ``failed``, ``lost data``), exit code, error line, wall
  time and figures. A campaign killed midway and started again with the same arguments
  redoes only the runs without a file (a run's id is derived from its spec, so a changed
  campaign never reuses another's results); ``--retry-failed`` redoes failed ones.
* ``results.parquet`` -- the columnar table, one row per run and figure (a failed run:
  one row with its error and no figure), in the campaign's run order; ``pandas.read_parquet``
  opens it.
* ``report.txt`` / ``report.json`` -- per figure: runs, mean, median, 5th/95th
  percentiles, bootstrap 95 % confidence interval of the mean and of the pass rate
  (Efron and Tibshirani 1993, percentile interval), and the number of failed runs;
  ``report-*.png`` -- a box plot with the runs' values per figure.
* ``bags/`` -- the runs' MCAP files when ``--keep-bags`` is given (a failed run's file
  is always kept).

Exit status: 0 when every run finished ``ok`` (a missed target is a figure, not a
failure), 1 when a run failed, 2 for bad input (one line).
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import math
import os
import re
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from mems_scenarios.figures import figures_of
from mems_sim.bag.output_paths import write_output
from mems_sim.cli_values import OneLineParser, number, positive

#: Figure columns of a result row, in the order ``run_scenario --json`` gives them.
FIGURE_KEYS = ("name", "value", "unit", "target", "pass", "source", "role")
#: Bootstrap resamples of the report's confidence intervals.
BOOTSTRAP = 2000


class CampaignError(ValueError):
    """Invalid campaign arguments (the message is one line)."""


@dataclass(frozen=True)
class RunSpec:
    """One run of a campaign: what ``run_scenario`` is given."""

    scenario: str
    seed: int
    device_seed: int | None = None
    temperature: float | None = None
    sets: tuple[str, ...] = ()
    duration_s: float | None = None

    @property
    def run_id(self) -> str:
        """Readable and unique: scenario, seeds, temperature, a hash of the rest."""
        parts = [self.scenario, f"s{self.seed}"]
        if self.device_seed is not None:
            parts.append(f"d{self.device_seed}")
        if self.temperature is not None:
            parts.append(f"t{self.temperature:g}")
        rest = json.dumps([list(self.sets), self.duration_s])
        parts.append(hashlib.sha1(rest.encode()).hexdigest()[:10])
        return "-".join(parts)

    def argv(self, bag: Path) -> list[str]:
        """``run_scenario`` arguments of this run, recording to ``bag``."""
        args = [self.scenario, "--seed", str(self.seed)]
        if self.device_seed is not None:
            args += ["--device-seed", str(self.device_seed)]
        if self.temperature is not None:
            args += ["--temperature", repr(self.temperature)]
        if self.duration_s is not None:
            args += ["--duration", repr(self.duration_s)]
        for s in self.sets:
            args += ["--set", s]
        # --overwrite: the campaign's own file of this run (a retried run replaces it)
        args += ["--out", str(bag), "--overwrite"]
        return args + ["--json", "--no-plots", "--no-progress"]


@dataclass
class RunResult:
    """What one run left: spec, status, figures (``run_scenario --json`` records)."""

    spec: RunSpec
    status: str
    exit_code: int
    error: str = ""
    wall_s: float = 0.0
    figures: list[dict] = field(default_factory=list)

    def to_json(self) -> str:
        d = asdict(self)
        d["spec"]["sets"] = list(self.spec.sets)
        d["run_id"] = self.spec.run_id
        return json.dumps(d, allow_nan=False)

    @classmethod
    def from_json(cls, text: str) -> RunResult:
        d = json.loads(text)
        spec = d.pop("spec")
        spec["sets"] = tuple(spec["sets"])
        d.pop("run_id", None)
        return cls(spec=RunSpec(**spec), **d)

    def rows(self) -> list[dict]:
        """One row per figure (a failed run: one row without figure)."""
        base = dict(
            run_id=self.spec.run_id,
            scenario=self.spec.scenario,
            seed=self.spec.seed,
            device_seed=self.spec.device_seed,
            temperature=self.spec.temperature,
            sets=" ".join(self.spec.sets),
            duration_s=self.spec.duration_s,
            status=self.status,
            exit_code=self.exit_code,
            error=self.error,
            wall_s=self.wall_s,
        )
        if not self.figures:
            return [dict(base, **{k: None for k in FIGURE_KEYS})]
        rows = []
        for f in self.figures:
            row = dict(base)
            for k in FIGURE_KEYS:
                v = f.get(k)
                row[k] = None if v is None else (v if k in ("value", "pass") else str(v))
            if isinstance(row["value"], str):  # a text figure: kept in the target's column
                row["target"] = f"{row['target'] or ''} (value {row['value']})".strip()
                row["value"] = None
            rows.append(row)
        return rows


# ---------------------------------------------------------------------- planning


#: Most runs one campaign plans (checked before anything is built), -.
MAX_RUNS = 100_000


def _too_many(what: str, n: int) -> CampaignError:
    return CampaignError(f"{what}: {n} runs is more than a campaign plans (at most {MAX_RUNS})")


def parse_ints(text: str, what: str) -> list[int]:
    """``A-B`` (inclusive) or ``A,B,C`` (or a mix: ``1-5,9``) -> ints in [0, 2^62], at most
    :data:`MAX_RUNS` of them (counted before the list is built)."""
    bounds = []
    for part in text.split(","):
        m = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", part)
        if m is None or (m.group(2) is not None and int(m.group(2)) < int(m.group(1))):
            raise CampaignError(f"{what} = {text!r} is invalid: A-B or A,B,C (integers)")
        bounds.append((int(m.group(1)), int(m.group(2) or m.group(1))))
    count = sum(hi - lo + 1 for lo, hi in bounds)
    if count > MAX_RUNS:
        raise _too_many(f"{what} = {text!r}", count)
    out: list[int] = []
    for lo, hi in bounds:
        out.extend(range(lo, hi + 1))
    if any(v > 2**62 for v in out):
        raise CampaignError(f"{what} = {text!r} is invalid: integers in [0, 2^62]")
    return out


def parse_floats(text: str, what: str) -> list[float]:
    """``T1,T2,...`` -> finite floats."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise CampaignError(f"{what} = {text!r} is invalid: comma-separated numbers") from None
    if not values or not all(math.isfinite(v) for v in values):
        raise CampaignError(f"{what} = {text!r} is invalid: finite numbers")
    return values


def _assignment(text: str, what: str) -> tuple[str, str]:
    key, sep, value = text.partition("=")
    if not sep or "." not in key or not value:
        raise CampaignError(f"{what} {text!r} is invalid: NODE.PARAM=VALUE")
    return key, value


def parameter_points(grid: list[str], draw: list[str], draws: int, draw_seed: int) -> list[tuple]:
    """``--set`` assignments of each parameter point: the product of the ``--grid``
    values, times ``draws`` uniform draws of the ``--draw`` ranges (seeded)."""
    axes = []
    for g in grid:
        key, values = _assignment(g, "--grid")
        axes.append([f"{key}={v}" for v in values.split(",")])
    size = math.prod(len(a) for a in axes) * (draws if draw else 1)
    if size > MAX_RUNS:
        raise _too_many("--grid and --draw", size)
    points = [tuple(p) for p in itertools.product(*axes)] if axes else [()]
    if not draw:
        return points
    ranges = []
    for d in draw:
        key, value = _assignment(d, "--draw")
        lo, sep, hi = value.partition(":")
        try:
            lo_f, hi_f = float(lo), float(hi)
        except ValueError:
            lo_f = hi_f = math.nan
        if not sep or not (math.isfinite(lo_f) and math.isfinite(hi_f) and lo_f <= hi_f):
            raise CampaignError(f"--draw {d!r} is invalid: NODE.PARAM=LO:HI with LO <= HI")
        ranges.append((key, lo_f, hi_f))
    rng = np.random.default_rng(draw_seed)
    drawn = [tuple(f"{k}={rng.uniform(lo, hi)!r}" for k, lo, hi in ranges) for _ in range(draws)]
    return [p + d for p in points for d in drawn]


def plan(args: argparse.Namespace) -> list[RunSpec]:
    """Every run of the campaign, in order (seeds innermost)."""
    seeds = parse_ints(args.seeds, "--seeds")
    dseeds = parse_ints(args.device_seeds, "--device-seeds") if args.device_seeds else [None]
    temps = parse_floats(args.temperatures, "--temperatures") if args.temperatures else [None]
    for s in args.set:
        _assignment(s, "--set")
    if args.draws < 1:
        raise CampaignError(f"--draws = {args.draws} is invalid: allowed >= 1")
    points = parameter_points(args.grid, args.draw, args.draws, args.draw_seed)
    total = len(points) * len(temps) * len(dseeds) * len(seeds)
    if total > MAX_RUNS:
        raise _too_many("the plan", total)
    return [
        RunSpec(args.name, s, d, t, tuple(args.set) + p, args.duration)
        for p in points
        for t in temps
        for d in dseeds
        for s in seeds
    ]


# ---------------------------------------------------------------------- one run


def _run_env() -> dict:
    env = dict(os.environ)
    env.pop("ROS_DOMAIN_ID", None)  # run_scenario leases a free domain of its own
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.setdefault("MPLBACKEND", "Agg")
    return env


def run_one(spec: RunSpec, out_dir: str, keep_bag: bool = False, timeout_s: float | None = None):
    """Run ``spec`` as ``run_scenario`` in a process of its own; returns a
    :class:`RunResult` (never raises for a failed run: its error is recorded)."""
    out = Path(out_dir)
    bag = out / "bags" / f"{spec.run_id}.mcap"
    bag.parent.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "mems_scenarios.cli", *spec.argv(bag)]
    start = time.monotonic()
    try:
        proc = subprocess.run(
            cmd, capture_output=True, text=True, env=_run_env(), timeout=timeout_s, check=False
        )
        code, stdout, stderr = proc.returncode, proc.stdout, proc.stderr
    except subprocess.TimeoutExpired as exc:
        code, stdout = -9, ""
        stderr = f"run_campaign: the run took longer than --run-timeout = {exc.timeout:g} s"
    wall = time.monotonic() - start
    errors = [ln for ln in stderr.splitlines() if "error" in ln.lower()] or stderr.splitlines()
    error = errors[-1].strip() if code != 0 and errors else ""
    figures: list[dict] = []
    if stdout.strip():
        try:
            figures = figures_of(json.loads(stdout))
        except (json.JSONDecodeError, ValueError):
            code = code or 1
            error = error or "run_scenario printed no JSON figures"
    status = "ok" if code == 0 else ("lost data" if code == 1 and figures else "failed")
    if code == 0 and not figures:
        status, error = "failed", "run_scenario printed no JSON figures"
    if status == "ok" and not keep_bag:
        bag.unlink(missing_ok=True)
    return RunResult(spec, status, int(code), error[:500], round(wall, 3), figures)


# ---------------------------------------------------------------------- storage


def write_text(path: Path, text: str) -> None:
    """Write a campaign file whole (a killed driver leaves it whole or absent), never
    through a symbolic link (:func:`~mems_sim.bag.output_paths.write_output`)."""
    write_output(path, lambda tmp: Path(tmp).write_text(text), overwrite=True)


#: The campaign's own files and directories in ``DIR`` (module doc); the report pages
#: ``report-<n>.png`` besides.
CAMPAIGN_ENTRIES = (
    "campaign.json",
    "results.parquet",
    "report.json",
    "report.txt",
    "runs",
    "bags",
)


def out_problem(out: Path) -> str | None:
    """Why the campaign directory ``out`` cannot be used (one line), or None: ``out`` or one
    of the campaign's entries in it is a symbolic link (never followed), or not of its kind
    (a file where a directory belongs, or the reverse). Existing files are the campaign's
    own (a campaign resumes): they are replaced."""
    if out.is_symlink():
        return f"{out}: is a symbolic link; refusing to write through it"
    if out.exists() and not out.is_dir():
        return f"{out}: exists and is not a directory"
    if not out.is_dir():
        return None
    pages = sorted(p.name for p in out.glob("report-*.png"))
    for name in (*CAMPAIGN_ENTRIES, *pages):
        path = out / name
        if path.is_symlink():
            return f"{path}: is a symbolic link; refusing to write through it"
        if path.exists() and path.is_dir() != (name in ("runs", "bags")):
            return f"{path}: is {'a directory' if path.is_dir() else 'not a directory'}"
    return None


def run_file(out: Path, spec: RunSpec) -> Path:
    return out / "runs" / f"{spec.run_id}.json"


def save_result(out: Path, result: RunResult) -> None:
    """Write a run's file atomically (a killed driver leaves it whole or absent)."""
    path = run_file(out, result.spec)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, result.to_json() + "\n")


def load_results(out: Path, specs: list[RunSpec]) -> dict[str, RunResult]:
    """Finished runs of ``specs`` found in ``out``."""
    done = {}
    for spec in specs:
        path = run_file(out, spec)
        if path.is_file():
            try:
                done[spec.run_id] = RunResult.from_json(path.read_text())
            except (ValueError, KeyError, TypeError):
                continue  # unreadable: run again
    return done


def write_table(out: Path, results: list[RunResult]) -> Path:
    """``results.parquet``: one row per run and figure (pyarrow)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    rows = [row for r in results for row in r.rows()]
    for row in rows:
        v = row["value"]
        row["value"] = None if v is None else float(v)
    schema = pa.schema(
        [
            ("run_id", pa.string()),
            ("scenario", pa.string()),
            ("seed", pa.int64()),
            ("device_seed", pa.int64()),
            ("temperature", pa.float64()),
            ("sets", pa.string()),
            ("duration_s", pa.float64()),
            ("status", pa.string()),
            ("exit_code", pa.int64()),
            ("error", pa.string()),
            ("wall_s", pa.float64()),
            ("name", pa.string()),
            ("value", pa.float64()),
            ("unit", pa.string()),
            ("target", pa.string()),
            ("pass", pa.bool_()),
            ("source", pa.string()),
            ("role", pa.string()),
        ]
    )
    path = out / "results.parquet"
    table = pa.Table.from_pylist(rows, schema=schema)
    write_output(path, lambda tmp: pq.write_table(table, tmp), overwrite=True)
    return path


# ---------------------------------------------------------------------- report


def bootstrap_ci(values: np.ndarray, stat=np.mean, n: int = BOOTSTRAP, seed: int = 0):
    """Percentile bootstrap 95 % interval of ``stat`` (Efron and Tibshirani 1993, ch. 13)."""
    values = np.asarray(values, float)
    if values.size < 2:
        v = float(stat(values)) if values.size else math.nan
        return v, v
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, values.size, size=(n, values.size))
    s = stat(values[idx], axis=1)
    return float(np.percentile(s, 2.5)), float(np.percentile(s, 97.5))


def report(results: list[RunResult]) -> dict:
    """Per figure statistics over the runs that finished (module doc)."""
    failed = [r for r in results if r.status != "ok"]
    names: dict[str, dict] = {}
    for r in results:
        if r.status != "ok":
            continue
        for f in r.figures:
            d = names.setdefault(f["name"], dict(unit=f.get("unit"), target=f.get("target")))
            v = f.get("value")
            d.setdefault("values", []).append(
                float(v) if isinstance(v, (int, float)) and v is not None else math.nan
            )
            if f.get("pass") is not None:
                d.setdefault("passes", []).append(bool(f["pass"]))
    figures = []
    for name, d in names.items():
        v = np.asarray(d.get("values", []), float)
        fin = v[np.isfinite(v)]
        rec = dict(name=name, unit=d["unit"], target=d["target"], runs=int(v.size))
        rec["non_finite"] = int(v.size - fin.size)
        if fin.size:
            rec.update(
                mean=float(fin.mean()),
                median=float(np.median(fin)),
                p5=float(np.percentile(fin, 5)),
                p95=float(np.percentile(fin, 95)),
            )
            lo, hi = bootstrap_ci(fin)
            rec.update(mean_ci_low=lo, mean_ci_high=hi)
        passes = d.get("passes")
        if passes:
            p = np.asarray(passes, float)
            lo, hi = bootstrap_ci(p)
            rec.update(pass_rate=float(p.mean()), pass_ci_low=lo, pass_ci_high=hi)
        figures.append(rec)
    return dict(
        runs=len(results),
        ok=len(results) - len(failed),
        failed=len(failed),
        failures=[dict(run_id=r.spec.run_id, status=r.status, error=r.error) for r in failed],
        figures=figures,
    )


def _g(v) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.4g}"


def report_text(rep: dict) -> str:
    """The report as a plain-text table."""
    from mems_sim.table import format_table

    rows = []
    for f in rep["figures"]:
        rate = f.get("pass_rate")
        rows.append(
            [
                f["name"],
                f["unit"] or "",
                f["target"] or "",
                str(f["runs"]),
                _g(f.get("mean")),
                f"[{_g(f.get('mean_ci_low'))}, {_g(f.get('mean_ci_high'))}]",
                _g(f.get("median")),
                f"[{_g(f.get('p5'))}, {_g(f.get('p95'))}]",
                "-"
                if rate is None
                else f"{100 * rate:.0f} % [{100 * f['pass_ci_low']:.0f}, "
                f"{100 * f['pass_ci_high']:.0f}]",
            ]
        )
    head = ["figure", "unit", "target", "runs", "mean", "95 % CI", "median", "5-95 %", "pass"]
    lines = [
        f"runs: {rep['runs']}, ok: {rep['ok']}, failed: {rep['failed']}",
        format_table(head, rows) if rows else "(no figures)",
    ]
    for f in rep["failures"]:
        lines.append(f"failed: {f['run_id']} ({f['status']}): {f['error']}")
    return "\n".join(lines)


def plot_report(out: Path, results: list[RunResult], per_page: int = 24) -> list[Path]:
    """Box plots of every numeric figure over the runs (``report-<page>.png``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    values: dict[str, list[float]] = {}
    units: dict[str, str] = {}
    for r in results:
        if r.status != "ok":
            continue
        for f in r.figures:
            v = f.get("value")
            if isinstance(v, (int, float)) and v is not None and math.isfinite(v):
                values.setdefault(f["name"], []).append(float(v))
                units[f["name"]] = f.get("unit") or ""
    names = sorted(values)
    paths = []
    for page in range(0, len(names), per_page):
        chunk = names[page : page + per_page]
        cols = min(4, len(chunk))
        rows = math.ceil(len(chunk) / cols)
        fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.6 * rows), squeeze=False)
        for ax, name in zip(axes.flat, chunk):
            ax.boxplot(values[name], orientation="vertical", widths=0.5)
            ax.plot(np.ones(len(values[name])), values[name], ".", alpha=0.5)
            ax.set_title(name, fontsize=8)
            ax.set_ylabel(units[name], fontsize=7)
            ax.set_xticks([])
            ax.tick_params(labelsize=7)
        for ax in list(axes.flat)[len(chunk) :]:
            ax.axis("off")
        fig.suptitle(f"{len(results)} runs", fontsize=9)
        fig.tight_layout()
        path = out / f"report-{page // per_page + 1}.png"
        write_output(path, lambda tmp, fig=fig: fig.savefig(tmp, dpi=90), overwrite=True)
        plt.close(fig)
        paths.append(path)
    return paths


# ---------------------------------------------------------------------- driver


#: Dask settings of the local cluster: its scheduler and workers still open an HTTP server
#: each (Dask starts one whatever the dashboard setting, on every interface by default);
#: here they serve no route and listen on the loopback interface only.
LOCAL_HTTP = {"distributed.scheduler.http.routes": [], "distributed.worker.http.routes": []}
LOOPBACK_ANY_PORT = "127.0.0.1:0"


def _client(args):
    """A Dask client: an existing cluster (``--scheduler``) or a local one of ``--workers``
    single-threaded workers in this process (Dask's in-process transport; the HTTP servers
    Dask always starts bound to 127.0.0.1 and serving nothing)."""
    import dask
    from distributed import Client, LocalCluster

    if args.scheduler:
        return Client(args.scheduler, timeout=args.connect_timeout), None
    # the runs are processes of their own: workers in this process (threads) only wait on
    # them, and start in a fraction of the time worker processes take
    with dask.config.set(LOCAL_HTTP):
        cluster = LocalCluster(
            n_workers=args.workers,
            threads_per_worker=1,
            processes=False,  # in-process transport between scheduler and workers
            dashboard_address=LOOPBACK_ANY_PORT,
            worker_dashboard_address=LOOPBACK_ANY_PORT,
            silence_logs=40,
        )
    return Client(cluster), cluster


def execute(specs: list[RunSpec], args, out: Path) -> list[RunResult]:
    """Run every spec without a result file (resume), saving each as it ends."""
    from tqdm import tqdm

    done = load_results(out, specs)
    if args.retry_failed:
        done = {k: v for k, v in done.items() if v.status == "ok"}
    todo = [s for s in specs if s.run_id not in done]
    bar = tqdm(
        total=len(specs),
        initial=len(specs) - len(todo),
        desc=f"campaign {args.name}",
        unit="run",
        disable=args.no_progress,
        file=sys.stderr,
    )
    try:
        if args.workers == 0 and not args.scheduler:
            for spec in todo:
                result = run_one(spec, str(out), args.keep_bags, args.run_timeout)
                save_result(out, result)
                done[spec.run_id] = result
                bar.update(1)
        elif todo:
            from distributed import as_completed

            client, cluster = _client(args)
            try:
                futures = client.map(
                    run_one,
                    todo,
                    out_dir=str(out.resolve()),
                    keep_bag=args.keep_bags,
                    timeout_s=args.run_timeout,
                    pure=False,
                )
                for future in as_completed(futures):
                    result = future.result()
                    save_result(out, result)
                    done[result.spec.run_id] = result
                    bar.update(1)
            finally:
                client.close()
                if cluster is not None:
                    cluster.close()
    finally:
        bar.close()
    return [done[s.run_id] for s in specs]


def _parser() -> argparse.ArgumentParser:
    p = OneLineParser(
        prog="run_campaign",
        description="Run a scenario over noise seeds, device seeds, temperatures and "
        "parameter points on Dask distributed; write the per-run table and a report.",
    )
    p.add_argument("name", help="scenario name (run_scenario --list)")
    p.add_argument("--seeds", required=True, help="noise seeds: A-B or A,B,C")
    p.add_argument("--device-seeds", default=None, help="device seeds: A-B or A,B,C")
    p.add_argument("--temperatures", default=None, help="temperatures [C]: T1,T2,...")
    p.add_argument(
        "--set", action="append", default=[], metavar="NODE.PARAM=VALUE", help="every run"
    )
    p.add_argument(
        "--grid", action="append", default=[], metavar="NODE.PARAM=V1,V2", help="grid axis"
    )
    p.add_argument(
        "--draw",
        action="append",
        default=[],
        metavar="NODE.PARAM=LO:HI",
        help="uniform random draw per point",
    )
    p.add_argument("--draws", type=int, default=1, help="random draws of --draw (default 1)")
    p.add_argument("--draw-seed", type=int, default=0, help="seed of the draws (default 0)")
    p.add_argument("--duration", type=float, default=None, help="scenario duration [s]")
    p.add_argument("--workers", type=int, default=None, help="local workers (0: serial)")
    p.add_argument("--scheduler", default=None, help="existing Dask scheduler address")
    p.add_argument(
        "--connect-timeout",
        type=number(0.0, 3600.0, lo_open=True),
        default=30.0,
        help=argparse.SUPPRESS,
    )
    p.add_argument("--out", required=True, type=Path, help="campaign directory")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("--keep-bags", action="store_true", help="keep every run's MCAP")
    p.add_argument("--retry-failed", action="store_true", help="run failed runs again")
    p.add_argument("--run-timeout", type=positive, default=None, help="per-run limit [s]")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def write_report(out: Path, results: list[RunResult]) -> tuple[Path, dict, list[Path]]:
    """Write the table, ``report.json``, ``report.txt`` and the report pages; returns the
    table's path, the report and the pages' paths. OSError (BagWriteError: one line)."""
    table = write_table(out, results)
    rep = report(results)
    write_text(out / "report.json", json.dumps(rep, indent=1) + "\n")
    write_text(out / "report.txt", report_text(rep) + "\n")
    return table, rep, plot_report(out, results)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``run_campaign``."""
    from mems_scenarios import SCENARIOS

    args = _parser().parse_args(argv)

    def fail(text: str) -> int:
        print(f"run_campaign: error: {text}", file=sys.stderr)
        return 2

    if args.name not in SCENARIOS:
        return fail(f"unknown scenario {args.name!r}: available are {', '.join(SCENARIOS)}")
    if args.workers is not None and args.scheduler:
        return fail("give --workers or --scheduler, not both")
    if args.workers is None and not args.scheduler:
        args.workers = os.cpu_count() or 1
    if args.workers is not None and not 0 <= args.workers <= 1024:
        return fail(f"--workers = {args.workers} is invalid: allowed [0, 1024]")
    if args.scheduler and not re.fullmatch(r"(tcp|tls|inproc|ucx)://\S+:\d+", args.scheduler):
        return fail(f"--scheduler {args.scheduler!r} is invalid: an address tcp://HOST:PORT")
    if args.duration is not None and not (0 < args.duration < 1e9):
        return fail(f"--duration = {args.duration!r} is invalid: allowed (0, 1e9) s")
    from mems_scenarios.cli import _parser as scenario_parser

    known = {o for a in scenario_parser()._actions for o in a.option_strings}
    for given, option in (
        (args.device_seeds, "--device-seed"),
        (args.temperatures, "--temperature"),
    ):
        if given and option not in known:
            return fail(f"{option}s: run_scenario has no {option} option in this version")
    try:
        specs = plan(args)
    except CampaignError as exc:
        return fail(str(exc))
    if len({s.run_id for s in specs}) != len(specs):
        return fail("the campaign names the same run twice (repeated seeds or points)")
    out: Path = args.out
    problem = out_problem(out)
    if problem is not None:
        return fail(f"--out: {problem}")
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_text(
            out / "campaign.json",
            json.dumps(dict(argv=sys.argv[1:] if argv is None else argv, runs=len(specs))) + "\n",
        )
    except OSError as exc:
        return fail(f"--out {str(out)!r}: {exc.strerror or exc}")
    try:
        results = execute(specs, args, out)
    except KeyboardInterrupt:
        return fail("interrupted; finished runs are kept, run the same command to resume")
    except OSError as exc:  # e.g. no scheduler at the address
        return fail(" ".join(str(exc).split()))
    try:
        table, rep, pngs = write_report(out, results)
    except OSError as exc:  # e.g. the disk is full: one line, the run files are kept
        return fail(f"{' '.join(str(exc).split())} (run the same command to write the report)")
    text = report_text(rep)
    if args.json:
        print(json.dumps(rep))
        print(text, file=sys.stderr)
    else:
        print(text)
        print(
            f"\ntable: {table}\nreport: {out / 'report.txt'}"
            + "".join(f"\nfigure: {p}" for p in pngs)
        )
    return 0 if rep["failed"] == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
