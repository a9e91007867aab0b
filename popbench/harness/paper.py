"""The paper's reported numbers (Tables I and II), transcribed so every table shows them beside
ours. Times are the paper's seconds; F is the paper's F(x) (its eq. 1 with unstated weights).

Table I: ``PAPER_TABLE1[dataset][robots][method] = (F, time_s)``.
Table II: ``PAPER_TABLE2[dataset][rate][method] = (F, precision, recall)``.
"""

from __future__ import annotations

_METHODS = ("cc-pgo", "ml-pgo", "mm-pgo", "prop-v1", "prop-v2")


def _row(values: tuple[float, ...], times: tuple[float, ...]) -> dict[int, dict[str, tuple]]:
    """15 F values and 15 times in the paper's column order (n = 3, 7, 35 × 5 methods)."""
    cells: dict[int, dict[str, tuple]] = {}
    for block, robots in enumerate((3, 7, 35)):
        cells[robots] = {
            method: (values[5 * block + k], times[5 * block + k])
            for k, method in enumerate(_METHODS)
        }
    return cells


PAPER_TABLE1: dict[str, dict[int, dict[str, tuple[float, float]]]] = {
    "m3500": _row(
        (1123, 923, 548, 407, 319, 1134, 932, 553, 428, 336, 1118, 917, 547, 455, 364),
        (575.64, 480.25, 185.37, 28.64, 42.93, 402.87, 336.09, 129.82, 20.04, 30.05)
        + (201.53, 168.12, 64.91, 10.03, 15.06),
    ),
    "m3500b": _row(
        (4.66e4, 3.01e4, 2.01e4, 1.43e4, 1.22e4, 4.67e4, 3.02e4, 2.02e4, 1.52e4, 1.31e4)
        + (4.66e4, 3.00e4, 2.01e4, 1.63e4, 1.41e4),
        (578.72, 482.03, 188.94, 28.97, 43.52, 405.11, 337.44, 132.19, 20.29, 30.42)
        + (202.47, 168.70, 66.07, 10.11, 15.24),
    ),
    "m3500c": _row(
        (5.64e4, 4.01e4, 2.31e4, 1.62e4, 1.31e4, 5.65e4, 4.02e4, 2.32e4, 1.73e4, 1.42e4)
        + (5.64e4, 4.00e4, 2.30e4, 1.82e4, 1.51e4),
        (577.83, 481.48, 186.52, 28.83, 42.78, 404.52, 337.02, 130.49, 20.23, 29.96)
        + (202.17, 168.51, 65.29, 10.10, 14.97),
    ),
    "city10k": _row(
        (4.52e4, 3.51e4, 5223, 5073, 4012, 4.53e4, 3.52e4, 5235, 5564, 4527)
        + (4.51e4, 3.50e4, 5219, 6044, 5023),
        (950.57, 810.27, 250.01, 44.97, 61.23, 665.35, 567.19, 175.04, 31.47, 42.76)
        + (332.69, 283.63, 87.48, 15.73, 21.39),
    ),
    "grid1000": _row(
        (3050, 1800, 1100, 950, 820, 3065, 1815, 1120, 1005, 880, 3040, 1790, 1090, 1035, 910),
        (225.50, 181.00, 73.00, 13.50, 19.30, 157.00, 128.00, 51.20, 9.80, 14.40)
        + (78.20, 63.00, 26.00, 5.00, 7.10),
    ),
    "intel": _row(
        (9.96e5, 6.01e4, 1023, 517, 412, 9.97e5, 6.02e4, 1041, 531, 421)
        + (9.96e5, 6.00e4, 1019, 549, 446),
        (220.40, 182.26, 72.53, 12.51, 18.79, 154.27, 127.58, 50.76, 8.81, 13.17)
        + (77.12, 63.75, 25.36, 4.43, 6.55),
    ),
    "mit": _row(
        (2048, 1249, 1021, 953, 809, 2049, 1252, 1024, 1003, 853, 2031, 1241, 1018, 1047, 892),
        (231.37, 185.21, 74.96, 14.46, 20.57, 161.95, 129.62, 52.47, 10.05, 14.38)
        + (80.98, 64.81, 26.19, 5.08, 7.21),
    ),
    "csail": _row(
        (3375, 2074, 1138, 945, 802, 3387, 2085, 1151, 1005, 856, 3362, 2063, 1139, 1036, 894),
        (235.47, 187.66, 75.92, 14.78, 21.07, 164.24, 131.43, 52.93, 10.34, 14.68)
        + (81.56, 65.21, 26.13, 5.17, 7.27),
    ),
}

# (F, precision, recall) per method at outlier rates 2.5 %, 5 %, 10 %.
PAPER_TABLE2: dict[str, dict[float, dict[str, tuple[float, float, float]]]] = {
    "intel": {
        0.025: {"prop-v1": (5.6e2, 0.93, 0.85), "mm-pgo": (1.1e3, 0.81, 0.66)},
        0.05: {"prop-v1": (8.4e2, 0.91, 0.82), "mm-pgo": (1.9e3, 0.77, 0.60)},
        0.10: {"prop-v1": (1.6e3, 0.88, 0.79), "mm-pgo": (3.4e3, 0.69, 0.55)},
    },
    "mit": {
        0.025: {"prop-v1": (8.1e2, 0.92, 0.84), "mm-pgo": (7.9e2, 0.80, 0.64)},
        0.05: {"prop-v1": (1.1e3, 0.90, 0.82), "mm-pgo": (2.3e3, 0.91, 0.58)},
        0.10: {"prop-v1": (2.0e3, 0.87, 0.78), "mm-pgo": (4.1e3, 0.67, 0.53)},
    },
    "csail": {
        0.025: {"prop-v1": (0.6e3, 0.94, 0.86), "mm-pgo": (1.1e3, 0.82, 0.87)},
        0.05: {"prop-v1": (1.2e3, 0.92, 0.83), "mm-pgo": (2.1e3, 0.79, 0.63)},
        0.10: {"prop-v1": (3.6e3, 0.89, 0.80), "mm-pgo": (6.4e3, 0.72, 0.57)},
    },
}


def paper_table1_cell(dataset: str, robots: int, method: str) -> tuple[float, float] | None:
    """The paper's ``(F, time_s)`` for a Table I cell, or None where the paper has none."""
    return PAPER_TABLE1.get(dataset, {}).get(robots, {}).get(method)


def paper_table2_cell(dataset: str, rate: float, method: str) -> tuple[float, float, float] | None:
    """The paper's ``(F, precision, recall)`` for a Table II cell, or None."""
    return PAPER_TABLE2.get(dataset, {}).get(round(rate, 4), {}).get(method)
