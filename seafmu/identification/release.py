"""Where a decay or a pendulum swing is released: a log that starts while the body is still held.

A decay trial's model starts at its first sample, free. Real logs often start a little before the
release, with the body held at its initial angle or speed; the held stretch then reads as motion
the model cannot make, and the diagnosis names effects that are not there (a clean roll decay
logged 0.6 s before its release: a cubic restoring term, quadratic drag and friction at once). The
leading hold is found and left out of the run (``held_samples``), and the trial says so.

How: over the samples until the output has moved a fifth of the way to its end value, the model
"held at c until t_r, then released" (c + b (t - t_r)^p after t_r: p = 2 for a body released from
rest against a restoring force, p = 1 for a speed decay, whose slope jumps at the release) is fitted
by least squares for every candidate t_r; the hold is real when the best t_r lies a few samples in
and lowers the squared error by more than ``MIN_GAIN`` times the sample noise variance against a
release at the first sample. Written here because no library finds a change point of this form
(``ruptures`` and the like find changes of mean or variance, and are not dependencies of seafmu).
"""

from __future__ import annotations

import numpy as np

from seafmu.identification.fitting import white_noise_std

RELEASE_KINDS = {"decay": 1, "decay2": 2, "pendulum": 2}  # trial kind -> power of the motion after release
MIN_HELD = 3  # samples: a shorter lead is within what noise moves a release's first samples
MIN_GAIN = 25.0  # squared-error drop, in noise variances (5 sigma), for a hold to be real
MAX_CANDIDATES = 400  # release instants tried (evenly spaced) in a long lead
DEPARTED = 0.2  # the fraction of the way to the end value that ends the window


def held_samples(t: np.ndarray, y: np.ndarray, kind: str) -> int:
    """The number of leading samples during which the body is held before its release (0: the log
    starts at the release, or ``kind`` is no release trial); the release is sample ``held_samples``."""
    p = RELEASE_KINDS.get(kind)
    if p is None or y.ndim != 1 or t is None or y.size < 20:
        return 0
    end = float(np.median(y[-max(5, y.size // 10):]))
    sigma = max(float(white_noise_std(y)), 1e-12 * float(np.max(np.abs(y)) or 1.0))
    moved = np.flatnonzero(np.abs(y - y[0]) > max(5.0 * sigma, DEPARTED * abs(y[0] - end)))
    if moved.size == 0 or moved[0] <= MIN_HELD:
        return 0
    w = min(y.size, int(moved[0]) + 1 + int(moved[0]) // 2)  # the lead and half as much of the departure
    tw, yw = t[:w] - t[0], y[:w]
    cands = np.unique(np.linspace(0, int(moved[0]) - 1, min(int(moved[0]), MAX_CANDIDATES)).astype(int))

    def sse(r: int) -> float:
        X = np.column_stack([np.ones(w), np.maximum(tw - tw[r], 0.0) ** p])
        coef, *_ = np.linalg.lstsq(X, yw, rcond=None)
        return float(np.sum((yw - X @ coef) ** 2))

    errs = np.array([sse(int(r)) for r in cands])  # cands[0] = 0: a release at the first sample
    best = int(cands[int(np.argmin(errs))])
    if best < MIN_HELD or errs[0] - float(np.min(errs)) < MIN_GAIN * sigma**2:
        return 0
    return best
