"""C++ DBSCAN (m3c.ground.dbscan) against scikit-learn's DBSCAN, timed in the same process on the same points.

Data: four dense clusters, isotropic Gaussians (sigma 0.1 m) centred on the corners of a 2 m square in the
horizontal plane; eps 0.1 m, min_samples 10. Both run single-threaded (scikit-learn's n_jobs=None). The
labels are checked for equality before a time is reported.

    PYTHONPATH=python python3 bench/ground_dbscan.py [--sizes 2000 20000 100000] [--repeat 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from sklearn.cluster import DBSCAN

from m3c.ground import dbscan

EPS, MIN_SAMPLES, SIGMA = 0.1, 10, 0.1
CENTRES = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 0.0, 2.0], [2.0, 0.0, 2.0]])


def four_clusters(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return CENTRES[rng.integers(0, 4, n)] + rng.normal(scale=SIGMA, size=(n, 3))


def best_time(fn, repeat: int):
    best, result = np.inf, None
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - start)
    return best, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[2000, 20000, 100000])
    parser.add_argument("--repeat", type=int, default=3,
                        help="best of this many runs (scikit-learn: a single run from 50k points)")
    args = parser.parse_args()
    print(f"four Gaussian clusters, sigma {SIGMA} m, eps {EPS} m, min_samples {MIN_SAMPLES}; "
          f"best of {args.repeat}")
    print(f"{'points':>8} {'m3c (s)':>10} {'sklearn (s)':>12} {'ratio':>8}  clusters  labels equal")
    for n in args.sizes:
        x = four_clusters(n)
        ours_s, labels = best_time(lambda: dbscan(x, EPS, MIN_SAMPLES), args.repeat)
        ref_s, ref = best_time(lambda: DBSCAN(eps=EPS, min_samples=MIN_SAMPLES).fit(x).labels_,
                               args.repeat if n < 50000 else 1)
        equal = np.array_equal(labels, ref)
        print(f"{n:>8} {ours_s:>10.4f} {ref_s:>12.3f} {ref_s / ours_s:>7.1f}x  {labels.max() + 1:>8}  "
              f"{equal}")
        if not equal:
            raise SystemExit("labels differ from scikit-learn's: the timing is not comparable")


if __name__ == "__main__":
    main()
