"""How long a simulated adaptive session takes to resume, against solving its estimates again.

Why: the adaptive planner chooses every touch from the batch solve after the last one, so
the session stores one batch solve per touch. Before session 66, ``varskin calibrate
--resume`` solved each of them again to bring the planner back to where it stopped, and
the arm waited for that. Now the stored ones are read back (``session.live_estimate``).

    python benchmarks/resume_adaptive.py [--budget 60] [--repeats 2]

It records one adaptive session on the simulated rig (launch/sim.yaml with the adaptive
planner and ``--budget`` touches), then resumes copies of its finished file, alternating:
- as ``varskin calibrate --resume`` runs now;
- with the session made to ignore the stored live estimates, so that it solves every
  touch's batch estimate again (what it did before).

Both start the simulated rig, hand the planner the same estimates, so it proposes the
stored touches and the robot touches nothing, then write the same final estimate and
report. Prints the median wall time of each and their ratio.
"""

from __future__ import annotations

import _one_core  # noqa: F401  (first: pins BLAS to one thread before numpy loads)

# isort: split
import argparse
import contextlib
import io
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from varskin import session  # noqa: E402
from varskin.cli import main as varskin  # noqa: E402
from varskin.patch import config_dir  # noqa: E402
from varskin.store import SessionStore  # noqa: E402


def quiet(argv: list[str]) -> None:
    """``varskin argv`` with its progress and report lines swallowed; raises on failure."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        rc = varskin(argv)
    if rc != 0:
        raise SystemExit(f"varskin {' '.join(argv)} exited with {rc}")


@contextlib.contextmanager
def stored_estimates_ignored():
    """The session solves every batch estimate again, as it did before session 66 (when it
    made a fast update before each too); the report still reads the stored ones."""
    real = session.live_estimate

    def solved_again(localizer, log, mode, batch_after_logs=None, shown=None):
        return real(localizer, log, mode, batch_after_logs)

    session.live_estimate = solved_again
    try:
        yield
    finally:
        session.live_estimate = real


def final_xy(db: Path) -> list:
    with SessionStore.open(db) as store:
        (final,) = store.estimates("final").values()
    return [(e.sensor, e.x_mm, e.y_mm, e.sigma_mm, e.status) for e in final]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=int, default=60, help="touches of the session; default 60")
    ap.add_argument("--repeats", type=int, default=2, help="resumes of each kind; default 2")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        launch = yaml.safe_load((ROOT / "launch" / "sim.yaml").read_text())
        launch["patch"] = str(config_dir() / "patch_b.yaml")
        launch["plan"]["mode"] = "adaptive"
        (tmp / "adaptive.yaml").write_text(yaml.safe_dump(launch))
        db = tmp / "session.db"
        t0 = time.perf_counter()
        quiet(
            ["calibrate", str(tmp / "adaptive.yaml"), "-o", str(db), "--budget", str(args.budget)]
        )
        with SessionStore.open(db) as store:
            n_logs, n_attempts = store.n_point_logs(), len(store.attempts())
        print(
            f"adaptive session, simulated Patch B, budget {args.budget}: {n_logs} point logs, "
            f"recorded in {time.perf_counter() - t0:.0f} s"
        )
        times: dict[str, list[float]] = {"read back": [], "solved again": []}
        finals = set()
        for r in range(args.repeats):
            for kind, hide in (("read back", False), ("solved again", True)):
                copy = tmp / f"resume{r}-{kind.replace(' ', '_')}.db"
                shutil.copy(db, copy)
                t0 = time.perf_counter()
                with stored_estimates_ignored() if hide else contextlib.nullcontext():
                    quiet(["calibrate", "--resume", str(copy)])
                times[kind].append(time.perf_counter() - t0)
                with SessionStore.open(copy) as store:
                    if len(store.attempts()) != n_attempts:
                        raise SystemExit(f"{kind}: the resume touched the patch again")
                finals.add(repr(final_xy(copy)))
        for kind, t in times.items():
            print(
                f"  resume, stored batch solves {kind}: median {statistics.median(t):.1f} s "
                f"over {len(t)} ({', '.join(f'{x:.1f}' for x in t)})"
            )
        ratio = statistics.median(times["solved again"]) / statistics.median(times["read back"])
        print(
            f"  solving again takes {ratio:.1f}x as long; final estimates identical: {len(finals) == 1}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
