"""LS-DYNA's ASCII histories as LS-DYNA prints them: fixed-width Fortran fields read by column.

The files are written here line by line in LS-DYNA's layout (nodout: the node id in columns 1–10, then fields of
12 columns, `i10,1p12e12.4`; rcforc: `master|slave ID time T  x FX  y FY  z FZ mass M`), with the forms that a
pattern of numbers misreads: a three-digit exponent without its "E", numbers that touch, and overflow asterisks.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from fringelab.formats.simulation_lsdyna_ascii import fortran_float, read_nodout, read_rcforc, write_nodout

HEADER = (" nodal point  x-disp     y-disp      z-disp      x-vel       y-vel       z-vel      x-accl      y-accl"
          "      z-accl      x-coor      y-coor      z-coor")  # fmt: skip


def block(step: int, time: str, rows: list[tuple[int, list[str]]]) -> list[str]:
    """One nodout time step as LS-DYNA writes it: each value right-aligned in its 12 columns."""
    lines = ["", "", f" n o d a l   p r i n t   o u t   f o r   t i m e  s t e p{step:8d}"
             f"                              ( at time {time} )", "", HEADER]  # fmt: skip
    for node, values in rows:
        fields = values + ["0.0000E+00"] * (12 - len(values))
        lines.append(f"{node:10d}" + "".join(f"{v:>12s}" for v in fields))
    return lines


def test_fortran_fields_without_e_and_with_three_digit_exponents() -> None:
    assert fortran_float(" -1.5000-345") == 0.0  # −1.5e-345 is below float64: zero, not −1.5
    assert fortran_float("1.2345+100") == pytest.approx(1.2345e100)
    assert fortran_float("-2.5000-05") == pytest.approx(-2.5e-5)
    assert fortran_float(" 3.0000D+01") == 30.0
    assert math.isnan(fortran_float("************"))
    assert math.isnan(fortran_float("1.0000+999"))  # beyond float64: missing, not inf


def test_nodout_read_by_column(tmp_path: Path) -> None:
    """A three-digit exponent reads as its value (the old pattern read −1.5), numbers that touch are split by
    their columns, and asterisks are missing (NaN, their line listed), not a number."""
    lines = [" ls-dyna  R13.1"]
    lines += block(1, "0.0000000E+00", [(12, ["0.0000E+00", "0.0000E+00", "0.0000E+00"]),
                                        (7, ["1.0000E+00", "0.0000E+00", "0.0000E+00"])])  # fmt: skip
    lines += block(2, "1.0000000E-03", [(12, ["-1.5000-345", "2.5000-05", "-1.2345E+02"]),
                                        (7, ["-1.23457E+01", "-9.87654E+00", "1.0000E+00"])])  # fmt: skip
    lines += block(3, "2.0000000E-03", [(12, ["1.0000E+00", "************", "-2.0000E+00"]),
                                        (7, ["1.0000E+00", "2.0000E+00", "3.0000E+00"])])  # fmt: skip
    path = tmp_path / "nodout"
    path.write_text("\n".join(lines) + "\n", encoding="latin-1")
    histories = read_nodout(path)
    np.testing.assert_array_equal(histories.node_ids, [12, 7])
    np.testing.assert_allclose(histories.time, [0.0, 1e-3, 2e-3])
    np.testing.assert_allclose(histories.displacement[1, 0], [0.0, 2.5e-5, -123.45])
    np.testing.assert_allclose(histories.displacement[1, 1], [-12.3457, -9.87654, 1.0])  # 12 columns each: touching
    assert np.isnan(histories.displacement[2, 0, 1]) and histories.displacement[2, 0, 2] == -2.0
    assert histories.missing_lines == (len(lines) - 1,)
    travel = histories.punch_travel(12)
    assert np.isnan(travel[2]) and travel[1] == pytest.approx(123.45)


def test_nodout_blocks_of_unequal_length_are_refused_by_line(tmp_path: Path) -> None:
    lines = [" ls-dyna"]
    lines += block(1, "0.0000000E+00", [(1, ["0.0000E+00"] * 3), (2, ["0.0000E+00"] * 3)])
    lines += block(2, "1.0000000E-03", [(1, ["0.0000E+00"] * 3)])
    path = tmp_path / "nodout"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"nodout: line 11: this time step lists 1 nodes .* the first \(line 4\) 2"):
        read_nodout(path)
    lines[-1] = lines[-1][:30]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"nodout: line 14: node 1: the line ends before x-, y- and z-disp"):
        read_nodout(path)
    lines[-1] = f"{1:10d}{'1.0000E+00':>12s}{'abc':>12s}{'1.0':>12s}"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"nodout: line 14: node 1, y-disp \(columns 23–34\): 'abc' is not a number"):
        read_nodout(path)


def test_nodout_writer_uses_the_columns_it_is_read_by(tmp_path: Path) -> None:
    displacement = np.random.default_rng(3).normal(0, 50.0, (3, 2, 3))
    displacement[1, 0, 0] = -1.5e-300  # a three-digit exponent: C prints it with its "E", which reads as well
    write_nodout(tmp_path / "nodout", time=np.array([0.0, 1.0, 2.0]), node_ids=np.array([123456789, 5]),
                 displacement=displacement, coordinates=np.zeros((2, 3)))  # fmt: skip
    histories = read_nodout(tmp_path / "nodout")
    np.testing.assert_allclose(histories.displacement, displacement, rtol=1e-4)  # 5 significant digits printed


def test_rcforc_fields_between_labels(tmp_path: Path) -> None:
    lines = [" r e s u l t a n t   i n t e r f a c e   f o r c e s", "", ""]
    rows = [("0.00000E+00", "0.00000E+00", "0.00000E+00", "0.00000E+00"),
            ("1.00000E-03", "-1.5000-345", "2.00000E+01", "-3.00000E+00"),
            ("2.00000E-03", "1.00000E+00", "************", "4.00000E+00")]  # fmt: skip
    for time, fx, fy, fz in rows:
        lines.append(f"  master{3:11d} time{time:>12s}  x {fx:>12s}  y {fy:>12s}  z {fz:>12s} mass {'0.0':>12s}")
        lines.append(f"  slave {3:11d} time{time:>12s}  x {fx:>12s}  y {fy:>12s}  z {fz:>12s} mass {'0.0':>12s}")
    path = tmp_path / "rcforc"
    path.write_text("\n".join(lines) + "\n")
    forces = read_rcforc(path)
    time, force = forces.series[(3, "master")]
    np.testing.assert_allclose(time, [0.0, 1e-3, 2e-3])
    np.testing.assert_allclose(force[1], [0.0, 20.0, -3.0])
    assert np.isnan(force[2, 1]) and forces.missing_lines == (8, 9)
    lines[5] = lines[5].replace("2.00000E+01", "2.0000x+01")
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"rcforc: line 6: 'y': '2.0000x\+01' is not a number"):
        read_rcforc(path)
