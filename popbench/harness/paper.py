"""The paper's reported numbers (Tables I and II), transcribed so every table shows them beside
ours. Times are the paper's seconds; F is the paper's F(x) (its eq. 1 with unstated weights).

Table I: ``PAPER_TABLE1[dataset][robots][method] = (F, time_s)``.
Table II: ``PAPER_TABLE2[dataset][rate][method] = (F, precision, recall)``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

Key = TypeVar("Key", int, float)

# Table I as printed: per dataset and team size n, each method's F and time (s).
_TABLE1 = """
dataset    n  cc-pgo           ml-pgo           mm-pgo           prop-v1          prop-v2
m3500      3  1123    575.64   923     480.25   548     185.37   407      28.64   319      42.93
m3500      7  1134    402.87   932     336.09   553     129.82   428      20.04   336      30.05
m3500     35  1118    201.53   917     168.12   547      64.91   455      10.03   364      15.06
m3500b     3  4.66e4  578.72   3.01e4  482.03   2.01e4  188.94   1.43e4   28.97   1.22e4   43.52
m3500b     7  4.67e4  405.11   3.02e4  337.44   2.02e4  132.19   1.52e4   20.29   1.31e4   30.42
m3500b    35  4.66e4  202.47   3.00e4  168.70   2.01e4   66.07   1.63e4   10.11   1.41e4   15.24
m3500c     3  5.64e4  577.83   4.01e4  481.48   2.31e4  186.52   1.62e4   28.83   1.31e4   42.78
m3500c     7  5.65e4  404.52   4.02e4  337.02   2.32e4  130.49   1.73e4   20.23   1.42e4   29.96
m3500c    35  5.64e4  202.17   4.00e4  168.51   2.30e4   65.29   1.82e4   10.10   1.51e4   14.97
city10k    3  4.52e4  950.57   3.51e4  810.27   5223    250.01   5073     44.97   4012     61.23
city10k    7  4.53e4  665.35   3.52e4  567.19   5235    175.04   5564     31.47   4527     42.76
city10k   35  4.51e4  332.69   3.50e4  283.63   5219     87.48   6044     15.73   5023     21.39
grid1000   3  3050    225.50   1800    181.00   1100     73.00   950      13.50   820      19.30
grid1000   7  3065    157.00   1815    128.00   1120     51.20   1005      9.80   880      14.40
grid1000  35  3040     78.20   1790     63.00   1090     26.00   1035      5.00   910       7.10
intel      3  9.96e5  220.40   6.01e4  182.26   1023     72.53   517      12.51   412      18.79
intel      7  9.97e5  154.27   6.02e4  127.58   1041     50.76   531       8.81   421      13.17
intel     35  9.96e5   77.12   6.00e4   63.75   1019     25.36   549       4.43   446       6.55
mit        3  2048    231.37   1249    185.21   1021     74.96   953      14.46   809      20.57
mit        7  2049    161.95   1252    129.62   1024     52.47   1003     10.05   853      14.38
mit       35  2031     80.98   1241     64.81   1018     26.19   1047      5.08   892       7.21
csail      3  3375    235.47   2074    187.66   1138     75.92   945      14.78   802      21.07
csail      7  3387    164.24   2085    131.43   1151     52.93   1005     10.34   856      14.68
csail     35  3362     81.56   2063     65.21   1139     26.13   1036      5.17   894       7.27
"""

# Table II as printed: per dataset and outlier rate, each method's F, precision and recall.
_TABLE2 = """
dataset rate   prop-v1            mm-pgo
intel   0.025  5.6e2  0.93  0.85  1.1e3  0.81  0.66
intel   0.05   8.4e2  0.91  0.82  1.9e3  0.77  0.60
intel   0.10   1.6e3  0.88  0.79  3.4e3  0.69  0.55
mit     0.025  8.1e2  0.92  0.84  7.9e2  0.80  0.64
mit     0.05   1.1e3  0.90  0.82  2.3e3  0.91  0.58
mit     0.10   2.0e3  0.87  0.78  4.1e3  0.67  0.53
csail   0.025  0.6e3  0.94  0.86  1.1e3  0.82  0.87
csail   0.05   1.2e3  0.92  0.83  2.1e3  0.79  0.63
csail   0.10   3.6e3  0.89  0.80  6.4e3  0.72  0.57
"""


def _parse(
    text: str, key: Callable[[str], Key], fields: int
) -> dict[str, dict[Key, dict[str, tuple[float, ...]]]]:
    """``table[dataset][key][method]`` of a transcribed table: a header ``dataset KEY METHOD…``,
    then one line per dataset and key with ``fields`` numbers under each method."""
    header, *lines = text.strip().splitlines()
    methods = header.split()[2:]
    table: dict[str, dict[Key, dict[str, tuple[float, ...]]]] = {}
    for line in lines:
        dataset, value, *numbers = line.split()
        cells = [float(number) for number in numbers]
        table.setdefault(dataset, {})[key(value)] = {
            method: tuple(cells[fields * k : fields * (k + 1)]) for k, method in enumerate(methods)
        }
    return table


PAPER_TABLE1: dict[str, dict[int, dict[str, tuple[float, ...]]]] = _parse(_TABLE1, int, 2)
PAPER_TABLE2: dict[str, dict[float, dict[str, tuple[float, ...]]]] = _parse(_TABLE2, float, 3)


def paper_table1_cell(dataset: str, robots: int, method: str) -> tuple[float, ...] | None:
    """The paper's ``(F, time_s)`` for a Table I cell, or None where the paper has none."""
    return PAPER_TABLE1.get(dataset, {}).get(robots, {}).get(method)


def paper_table2_cell(dataset: str, rate: float, method: str) -> tuple[float, ...] | None:
    """The paper's ``(F, precision, recall)`` for a Table II cell, or None."""
    return PAPER_TABLE2.get(dataset, {}).get(round(rate, 4), {}).get(method)
