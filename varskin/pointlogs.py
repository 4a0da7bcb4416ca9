"""Point logs in memory: every sensor's response to every touch at a known point.

A *point log* is one touch: where the probe was (patch mm) and what each sensor read,
averaged over the touch's samples. ``PointLogs`` holds a session's worth in arrays so
localizers can work column by column (one column = one sensor's *point log map*). The
CSV interchange format lives in ``varskin.pointlog_csv``; this module is format-free.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# A touch coordinate beyond a kilometre (a patch spans centimetres) is a mistake or damage in
# a file, not a position: refused where files are read, before it reaches the probes' hull
# and the plots as a 1e18 mm point.
MAX_COORD_MM = 1e6
# Likewise a touch time beyond ~30 years of session (its drift model would be singular).
MAX_TIME_S = 1e9


def touch_spacing_mm(points: np.ndarray) -> float:
    """Median distance of each touch to its nearest distinct one (the localizer's spacing);
    0 with fewer than two distinct touches."""
    if len(points) < 2:
        return 0.0
    d = np.hypot(points[:, None, 0] - points[None, :, 0], points[:, None, 1] - points[None, :, 1])
    d = np.where(d > 1e-6, d, np.inf)
    nn = d.min(axis=1)
    nn = nn[np.isfinite(nn)]
    return float(np.median(nn)) if nn.size else 0.0


@dataclass(frozen=True)
class PointLog:
    """One touch, as it arrives from a live session or a file."""

    touch: int
    x_mm: float
    y_mm: float
    values: np.ndarray  # (N,) mean response, relative to rest where a baseline was known
    n_samples: int = 1
    sample_sd: np.ndarray | None = None  # (N,) std of the samples within the touch
    t_s: float | None = None
    force_n: float | None = None


@dataclass
class PointLogs:
    """All touches of a session, sensor-major arrays for the localizers."""

    sensors: tuple[str, ...]
    touch: np.ndarray  # (K,) int touch ids
    xy_mm: np.ndarray  # (K, 2) probe locations
    values: np.ndarray  # (K, N) float64, relative to rest if ``rest`` is given
    n_samples: np.ndarray  # (K,) samples averaged into each row
    sample_sd: np.ndarray | None = None  # (K, N)
    rest: np.ndarray | None = None  # (N,) S0, mean of baseline samples (raw counts)
    rest_sd: np.ndarray | None = None  # (N,) sigma0, std of baseline samples
    t_s: np.ndarray | None = None  # (K,)
    force_n: np.ndarray | None = None  # (K,)
    source: str = "<memory>"
    warnings: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.touch)

    @property
    def n_sensors(self) -> int:
        return len(self.sensors)

    def logs(self):
        """Iterate the touches as ``PointLog`` records (the live-stream view)."""
        for k in range(len(self)):
            yield PointLog(
                touch=int(self.touch[k]),
                x_mm=float(self.xy_mm[k, 0]),
                y_mm=float(self.xy_mm[k, 1]),
                values=self.values[k],
                n_samples=int(self.n_samples[k]),
                sample_sd=None if self.sample_sd is None else self.sample_sd[k],
                t_s=None if self.t_s is None else float(self.t_s[k]),
                force_n=None if self.force_n is None else float(self.force_n[k]),
            )

    def subset(self, rows) -> PointLogs:
        """The same session restricted to some touches (index array or boolean mask)."""
        rows = np.asarray(rows)

        def pick(a):
            return None if a is None else a[rows]

        return PointLogs(
            sensors=self.sensors,
            touch=self.touch[rows],
            xy_mm=self.xy_mm[rows],
            values=self.values[rows],
            n_samples=self.n_samples[rows],
            sample_sd=pick(self.sample_sd),
            rest=self.rest,
            rest_sd=self.rest_sd,
            t_s=pick(self.t_s),
            force_n=pick(self.force_n),
            source=self.source,
            warnings=list(self.warnings),
        )

    @classmethod
    def from_logs(
        cls,
        sensors: tuple[str, ...] | list[str],
        logs: list[PointLog],
        rest: np.ndarray | None = None,
        rest_sd: np.ndarray | None = None,
        source: str = "<memory>",
    ) -> PointLogs:
        n = len(sensors)
        k = len(logs)
        has_sd = k > 0 and all(g.sample_sd is not None for g in logs)
        has_t = k > 0 and all(g.t_s is not None for g in logs)
        has_f = k > 0 and all(g.force_n is not None for g in logs)
        return cls(
            sensors=tuple(sensors),
            touch=np.array([g.touch for g in logs], dtype=np.int64),
            xy_mm=np.array([[g.x_mm, g.y_mm] for g in logs], float).reshape(k, 2),
            values=np.array([g.values for g in logs], float).reshape(k, n),
            n_samples=np.array([g.n_samples for g in logs], dtype=np.int64),
            sample_sd=np.array([g.sample_sd for g in logs], float).reshape(k, n)
            if has_sd
            else None,
            rest=rest,
            rest_sd=rest_sd,
            t_s=np.array([g.t_s for g in logs], float) if has_t else None,
            force_n=np.array([g.force_n for g in logs], float) if has_f else None,
            source=source,
        )


# Frame rows averaged per pass of ``average_samples`` (bounds its temporaries to ~10 MB).
AVERAGE_BLOCK_ROWS = 4096


def average_samples(
    sensors: tuple[str, ...] | list[str],
    touch: np.ndarray,
    xy_mm: np.ndarray,
    samples: np.ndarray,
    baseline: np.ndarray | None = None,
    t_s: np.ndarray | None = None,
    force_n: np.ndarray | None = None,
    source: str = "<memory>",
) -> PointLogs:
    """Average per-frame samples into one point log per touch id.

    ``touch`` (M,), ``xy_mm`` (M, 2), ``samples`` (M, N) are frame rows; rows sharing a touch
    id are one touch. Non-finite samples are skipped per cell and counted in ``warnings``; a
    touch with no finite sample for some sensor is dropped with a warning. ``baseline``
    (B, N) no-contact frames give S0 and sigma0 and are subtracted from the values.
    """
    sensors = tuple(sensors)
    warnings: list[str] = []
    samples = np.asarray(samples, float)
    ids, inverse = np.unique(np.asarray(touch), return_inverse=True)
    k, n = len(ids), samples.shape[1] if samples.ndim == 2 else len(sensors)
    counts = np.zeros((k, n))
    sums = np.zeros((k, n))
    sq = np.zeros((k, n))
    # Block by block: a whole-array pass holds several temporaries of the samples' size,
    # which for a full board's 1,000-touch recording (45,000 x 252 frames) was 4x its 90 MB.
    step = AVERAGE_BLOCK_ROWS
    blocks = [slice(a, a + step) for a in range(0, len(inverse), step)]
    n_bad = 0
    for b in blocks:
        finite = np.isfinite(samples[b])
        n_bad += int(finite.size - np.count_nonzero(finite))
        np.add.at(counts, inverse[b], finite)
        np.add.at(sums, inverse[b], np.where(finite, samples[b], 0.0))
    if n_bad:
        warnings.append(f"{source}: skipped {n_bad} non-finite sample(s)")
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = sums / counts
        # Two-pass variance keeps precision with raw counts around 10,000.
        for b in blocks:
            dev = np.where(np.isfinite(samples[b]), samples[b] - mean[inverse[b]], 0.0)
            np.add.at(sq, inverse[b], dev * dev)
        sd = np.sqrt(sq / np.maximum(counts - 1, 1))
    rows = np.bincount(inverse, minlength=k)
    first = np.zeros(k, dtype=np.int64)
    first[inverse[::-1]] = np.arange(len(inverse))[::-1]
    keep = (counts > 0).all(axis=1)
    if not keep.all():
        dropped = ", ".join(str(i) for i in ids[~keep][:10])
        warnings.append(f"{source}: dropped touch(es) {dropped} with no valid sample")
    rest = rest_sd = None
    if baseline is not None and len(baseline):
        baseline = np.asarray(baseline, float)
        with np.errstate(invalid="ignore"):
            rest = np.nanmean(np.where(np.isfinite(baseline), baseline, np.nan), axis=0)
            rest_sd = np.nanstd(np.where(np.isfinite(baseline), baseline, np.nan), axis=0, ddof=1)
        mean = mean - rest
    xy = np.asarray(xy_mm, float)[first]

    def per_touch(a):
        if a is None:
            return None
        a = np.asarray(a, float)
        return (np.bincount(inverse, weights=a, minlength=k) / np.maximum(rows, 1))[keep]

    return PointLogs(
        sensors=sensors,
        touch=ids[keep].astype(np.int64),
        xy_mm=xy[keep],
        values=mean[keep],
        n_samples=counts[keep].min(axis=1).astype(np.int64),
        sample_sd=sd[keep],
        rest=rest,
        rest_sd=rest_sd,
        t_s=per_touch(t_s),
        force_n=per_touch(force_n),
        source=source,
        warnings=warnings,
    )
