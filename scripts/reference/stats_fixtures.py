"""Print the fixtures the paired-comparison statistics are tested against (test time only).

    python scripts/reference/stats_fixtures.py tests/fixtures

needs statsmodels and scipy (e.g. a venv with `pip install statsmodels scipy`). Writes
- mcnemar_statsmodels.csv: statsmodels.stats.contingency_tables.mcnemar(table, exact=True);
- newcombe_paired.csv: Newcombe (1998) method 10, written here from the paper's formula on top of
  statsmodels' Wilson intervals (statsmodels has no paired Newcombe interval);
- sample_size_statsmodels.csv: statsmodels.stats.proportion.samplesize_proportions_2indep_onetail.
"""

import itertools
import math
import sys
from pathlib import Path

import numpy as np
import statsmodels
from statsmodels.stats.contingency_tables import mcnemar
from statsmodels.stats.proportion import proportion_confint, samplesize_proportions_2indep_onetail


def newcombe_paired(n11, n10, n01, n00, level):
    """Newcombe 1998 method 10 for p1 - p2, p1 = (n11 + n10)/n, p2 = (n11 + n01)/n."""
    n = n11 + n10 + n01 + n00
    alpha = 1 - level
    l1, u1 = proportion_confint(n11 + n10, n, alpha=alpha, method="wilson")
    l2, u2 = proportion_confint(n11 + n01, n, alpha=alpha, method="wilson")
    p1, p2 = (n11 + n10) / n, (n11 + n01) / n
    margins = (n11 + n10) * (n01 + n00) * (n11 + n01) * (n10 + n00)
    a = n11 * n00 - n10 * n01
    if margins == 0 or 0 <= a <= n / 2:
        phi = 0.0
    elif a > n / 2:
        phi = (a - n / 2) / math.sqrt(margins)
    else:
        phi = a / math.sqrt(margins)
    lo = p1 - p2 - math.sqrt((p1 - l1) ** 2 - 2 * phi * (p1 - l1) * (u2 - p2) + (u2 - p2) ** 2)
    hi = p1 - p2 + math.sqrt((u1 - p1) ** 2 - 2 * phi * (u1 - p1) * (p2 - l2) + (p2 - l2) ** 2)
    return lo, hi


def main(out: Path):
    version = statsmodels.__version__
    counts = [0, 1, 2, 3, 5, 8, 13, 25, 50, 120, 480]
    with open(out / "mcnemar_statsmodels.csv", "w") as f:
        f.write(f"# statsmodels {version} mcnemar([[n11, b], [c, n00]], exact=True).pvalue\nb,c,p\n")
        for b, c in itertools.product(counts, counts):
            p = mcnemar(np.array([[10, b], [c, 10]]), exact=True).pvalue
            f.write(f"{b},{c},{float(p)!r}\n")

    tables = [
        (0, 0, 0, 1), (1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (5, 0, 0, 5), (10, 0, 0, 0),
        (0, 10, 0, 0), (0, 5, 5, 0), (3, 2, 1, 4), (40, 3, 9, 48), (45, 4, 1, 0), (48, 0, 2, 0),
        (1, 1, 7, 12), (59, 6, 16, 80), (200, 30, 45, 225), (450, 20, 12, 18), (480, 0, 10, 10),
        (7, 1, 0, 2), (2, 9, 11, 3), (0, 4, 6, 0), (30, 0, 0, 20), (25, 25, 25, 25),
    ]
    with open(out / "newcombe_paired.csv", "w") as f:
        f.write(
            f"# Newcombe (1998) method 10 for p1 - p2 (python, on statsmodels {version} Wilson intervals)\n"
            "n11,n10,n01,n00,level,lo,hi\n"
        )
        for t, level in itertools.product(tables, [0.95, 0.9, 0.99]):
            lo, hi = newcombe_paired(*t, level)
            f.write(f"{t[0]},{t[1]},{t[2]},{t[3]},{level},{lo!r},{hi!r}\n")

    with open(out / "sample_size_statsmodels.csv", "w") as f:
        f.write(
            f"# statsmodels {version} samplesize_proportions_2indep_onetail(p2 - p1, p1, power, alpha=alpha)\n"
            "p1,p2,alpha,power,n\n"
        )
        for p1, delta, alpha, power in itertools.product(
            [0.05, 0.3, 0.5, 0.8, 0.9, 0.95], [-0.2, -0.05, 0.02, 0.05, 0.1, 0.2], [0.05, 0.01], [0.8, 0.9]
        ):
            p2 = round(p1 + delta, 10)
            if not 0 <= p2 <= 1:
                continue
            n = samplesize_proportions_2indep_onetail(p2 - p1, p1, power, alpha=alpha)
            f.write(f"{p1},{p2},{alpha},{power},{float(n)!r}\n")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
