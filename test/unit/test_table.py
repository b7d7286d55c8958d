"""table.py: delimited number tables read exactly or refused. Survey and prism rows written the ways
spreadsheets write them (every delimiter, both decimal marks, thousands separators, quotes, a header, a
byte-order mark, Windows-1252) read back to the numbers written; rows that read two ways, and rows that
read no way, are refused with their line."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.offline.cli import main
from aruco_abs_orient.offline.prism import PrismLogError, read_prism
from aruco_abs_orient.survey import SurveyError, read_csv_points, read_points
from aruco_abs_orient.table import read_table

DELIMS = {",": ",", ";": ";", "tab": "\t", "blank": " "}


def _format(value: float, mark: str, grouped: bool) -> str:
    """``value`` as a spreadsheet writes it: ``mark`` as the decimal mark, thousands grouped with the other
    mark (or an apostrophe, the Swiss way) when ``grouped``."""
    text = f"{value:.4f}"
    whole, frac = text.split(".")
    sign = "-" if whole.startswith("-") else ""
    whole = whole.lstrip("-")
    if grouped and len(whole) > 3:
        sep = "'" if mark == "." else "."
        groups = []
        while len(whole) > 3:
            groups.insert(0, whole[-3:])
            whole = whole[:-3]
        whole = sep.join([whole] + groups)
    return f"{sign}{whole}{mark}{frac}"


@settings(max_examples=60)
@given(delim=st.sampled_from(sorted(DELIMS)), mark=st.sampled_from([".", ","]), grouped=st.booleans(),
       header=st.booleans(), bom=st.booleans(), quoted=st.booleans(),
       xyz=st.lists(st.tuples(*[st.floats(-3e6, 3e6, allow_nan=False)] * 3), min_size=1, max_size=6))
def test_a_survey_csv_written_any_way_reads_back_exactly(tmp_path_factory, delim, mark, grouped, header, bom, quoted,
                                                        xyz):
    if delim == "," and mark == ",":
        mark = "."  # a decimal comma between commas is no CSV
    if quoted and delim == "blank":
        quoted = False
    sep = DELIMS[delim]
    q = '"' if quoted else ""
    lines = [sep.join(["Punkt", "E", "N", "H"])] if header else []
    for i, p in enumerate(xyz):
        lines.append(sep.join([f"M{i}"] + [q + _format(v, mark, grouped) + q for v in p]))
    path = tmp_path_factory.mktemp("csv") / "survey.csv"
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + ("\r\n".join(lines) + "\r\n").encode())
    try:
        points = read_csv_points(str(path))
    except SurveyError as e:  # refused only when the rows truly read two ways (thousands vs decimals)
        assert "reads two ways" in str(e) and "\n" not in str(e)
        points = read_csv_points(str(path), delim, mark)
    np.testing.assert_allclose([p.xyz for p in points], np.round(np.array(xyz), 4), rtol=0, atol=1e-9)
    assert [p.name for p in points] == [f"M{i}" for i in range(len(xyz))]


def test_the_issues_swiss_csv_reads_as_written(tmp_path):
    path = tmp_path / "survey.csv"
    path.write_bytes(b"\xef\xbb\xbfid;E;N;H\r\n3;1,5;2,5;0,3\r\n4;2;1;0,25\r\n")
    pts = read_points(str(path))
    np.testing.assert_allclose(pts[0].xyz, [1.5, 2.5, 0.3])
    np.testing.assert_allclose(pts[1].xyz, [2.0, 1.0, 0.25])
    assert pts[0].name == "3"  # the byte-order mark is not part of the first field


def test_a_row_that_reads_two_ways_is_refused_with_its_line_and_read_as_told(tmp_path, capsys):
    path = tmp_path / "survey.csv"
    path.write_text("# site A\n7;1,234;5,678;400\n8;2,000;3,500;401\n")
    with pytest.raises(SurveyError, match=r"survey\.csv:2: .* reads two ways: 7, 1234, 5678, 400 .* or "
                                          r"7, 1\.234, 5\.678, 400 .*give --decimal"):
        read_points(str(path))
    out = tmp_path / "m.yaml"
    assert main(["markers", str(path), "--size", "0.19", "--out", str(out)]) == 2
    assert "reads two ways" in capsys.readouterr().err
    assert main(["markers", str(path), "--size", "0.19", "--decimal", ",", "--out", str(out)]) == 0
    import yaml

    assert yaml.safe_load(out.read_text())["markers"][0]["position"] == [1.234, 5.678, 400.0]


@pytest.mark.parametrize("text,line,what", [
    ("3,1,5,2,5,0,3\n", 1, "any delimiter"),                      # decimal commas between commas: no reading
    ("1;1.5;2.5;0.3\n2;1,5;2,5;0,3\n", 2, "';' between fields, '.' decimal mark"),  # mixed decimal marks
    ("1,1.5,2.5,0.3\n2,1.5,2.5\n", 2, "',' between fields"),       # a field missing
    ("1,1.5,2.5,0.3,7\n", 1, "any delimiter"),                    # one too many (was read as its first four)
])
def test_rows_that_read_no_way_are_named(tmp_path, text, line, what):
    path = tmp_path / "s.csv"
    path.write_text(text)
    with pytest.raises(SurveyError, match=rf"s\.csv:{line}: expected 'id, E, N, H' with {what}") as e:
        read_csv_points(str(path))
    assert "\n" not in str(e.value)


def test_given_options_are_obeyed_and_a_contradiction_is_named(tmp_path):
    path = tmp_path / "s.csv"
    path.write_text("1;2;3;4\n")
    assert read_csv_points(str(path), ";", ".")[0].xyz.tolist() == [2.0, 3.0, 4.0]
    with pytest.raises(SurveyError, match=r"s\.csv:1: expected 'id, E, N, H' with ',' between fields"):
        read_csv_points(str(path), ",")
    with pytest.raises(SurveyError, match="',' between fields and ',' as the decimal mark"):
        read_csv_points(str(path), ",", ",")


def test_a_prism_log_with_decimal_commas_and_a_header_reads_exactly(tmp_path):
    path = tmp_path / "prism.csv"
    path.write_bytes("Zeit;Ost;Nord;Höhe\n".encode("cp1252").replace(b"Zeit;Ost;Nord", b"t;east;north")
                     + b"1700000000,05;2600001,5;1200002,25;400,125\n1700000000,1;2600001,6;1200002,3;nan\n"
                       b"1700000000,15;2600001,7;1200002,35;400,2\n")
    log = read_prism(str(path))
    np.testing.assert_allclose(log.stamps, [1700000000.05, 1700000000.15])
    np.testing.assert_allclose(log.positions[0], [2600001.5, 1200002.25, 400.125])
    assert log.skipped == {"NaN/inf prism position": 1}


def test_a_prism_row_that_reads_two_ways_is_refused(tmp_path):
    path = tmp_path / "prism.csv"
    path.write_text("1700000000;2,600;1,200;400\n1700000001;2,601;1,201;400\n")
    with pytest.raises(PrismLogError, match=r"prism\.csv:1: .*reads two ways"):
        read_prism(str(path))


def test_read_table_takes_the_named_columns_of_a_header():
    t = read_table("f", "x y z t extra\n1 2 3 10 a\n4 5 6 11 b\n", (0, 1, 2, 3), 4, ValueError, "row",
                   header_columns=lambda h: [h.index(k) for k in "txyz"] if set("txyz") <= set(h) else None)
    assert [r for _, r in t.rows] == [[10.0, 1.0, 2.0, 3.0], [11.0, 4.0, 5.0, 6.0]]
    assert t.header == ["x", "y", "z", "t", "extra"] and t.delimiter is None
