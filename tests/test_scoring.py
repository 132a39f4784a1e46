"""Scoring per the contract: position and orientation error, coverage, statistics."""

from __future__ import annotations

import numpy as np
import pytest

from radiopose.errors import InputError
from radiopose.estimates import Estimates, read_estimates_csv, write_estimates_csv
from radiopose.evaluate import error_stats, score
from radiopose.evaluate.scoring import unambiguous_tolerance_s
from radiopose.packets import Truth

TX = "02:00:00:00:00:01"


def _truth(n=10) -> Truth:
    t = np.arange(n) * 0.005
    pos = np.column_stack([np.arange(n, dtype=float), np.zeros(n), np.ones(n)])
    ori = np.column_stack([np.full(n, 10.0), np.zeros(n), np.zeros(n)])
    return Truth(t, np.full(n, TX, object), pos, ori)


def _est(truth, rows, method="full", dpos=(0, 0, 0), daz=0.0) -> Estimates:
    rows = np.asarray(rows)
    n = rows.size
    return Estimates(
        truth.timestamp_s[rows] + 1e-10,
        np.full(n, TX.upper(), object),
        np.array([str(r) for r in rows], object),
        truth.position_m[rows] + np.array(dpos),
        truth.orientation_deg[rows] + np.array([daz, 0, 0]),
        np.full(n, method, object),
    )


def test_errors_and_coverage():
    tr = _truth()
    (s,) = score(tr, _est(tr, [0, 2, 4, 6], dpos=(3, 4, 0), daz=-20.0))
    assert s.method == "full" and s.n_estimates == 4 and s.coverage == pytest.approx(0.4)
    assert s.position_m.mean == pytest.approx(5.0) and s.position_m.p95 == pytest.approx(5.0)
    assert s.orientation_deg.median == pytest.approx(20.0)  # 10° vs 350°: wrapped


def test_per_method_rows_and_position_only_lms():
    tr = _truth()
    a, b = _est(tr, [1, 2]), _est(tr, [1, 2, 3], method="lms", daz=90.0)
    est = Estimates(
        *(
            np.concatenate([getattr(a, f), getattr(b, f)])
            for f in (
                "timestamp_s",
                "transmitter",
                "packet_id",
                "position_m",
                "orientation_deg",
                "method",
            )
        )
    )
    full, lms = score(tr, est)
    assert (full.method, lms.method) == ("full", "lms")
    assert lms.coverage == pytest.approx(0.3) and lms.orientation_deg is None
    assert full.orientation_deg.mean == pytest.approx(0.0)


def test_empty_estimates_score_zero_coverage():
    tr = _truth()
    (s,) = score(tr, _est(tr, np.array([], int)))
    assert s.method == "none" and s.coverage == 0.0 and s.position_m.mean is None


def test_estimate_without_truth_is_an_error():
    tr = _truth()
    e = _est(tr, [1])
    e = Estimates(
        e.timestamp_s + 1.0,
        *(
            getattr(e, f)
            for f in ("transmitter", "packet_id", "position_m", "orientation_deg", "method")
        ),
    )
    with pytest.raises(InputError, match="no truth row"):
        score(tr, e)


def test_score_cli_names_the_estimates_file_and_line(tmp_path, capsys):
    from radiopose.cli import main
    from radiopose.estimates import write_estimates_csv
    from radiopose.packets import write_truth_csv

    tr = _truth()
    e = _est(tr, [0, 1, 2])
    e = Estimates(
        e.timestamp_s + np.array([0.0, 0.0, 1.0]),
        *(
            getattr(e, f)
            for f in ("transmitter", "packet_id", "position_m", "orientation_deg", "method")
        ),
    )
    write_truth_csv(tr, tmp_path / "truth.csv")
    write_estimates_csv(e, tmp_path / "est.csv")
    code = main(["score", str(tmp_path / "truth.csv"), str(tmp_path / "est.csv")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert f"{tmp_path / 'est.csv'}:4, column 'timestamp_s': estimate 3" in err


def test_score_cli_tolerance_for_synced_times(tmp_path, capsys):
    """Packets that went through pcap and ``sync`` come back within 0.1 ms of
    their simulated times: the default window (just under half the truth's
    5 ms spacing) matches them, as ``--tolerance-ms 0.1`` does; 1 µs refuses
    them and names the option; an estimate 2.5 ms off (as near to the next row
    as to its own) is refused by the default; a bad tolerance is one line."""
    from radiopose.cli import main
    from radiopose.estimates import write_estimates_csv
    from radiopose.packets import write_truth_csv

    tr = _truth()
    e = _est(tr, [0, 1, 2])
    e = Estimates(
        e.timestamp_s + 40e-6,  # 40 µs off, as sync's clock estimate may be
        *(
            getattr(e, f)
            for f in ("transmitter", "packet_id", "position_m", "orientation_deg", "method")
        ),
    )
    write_truth_csv(tr, tmp_path / "truth.csv")
    write_estimates_csv(e, tmp_path / "est.csv")
    args = ["score", str(tmp_path / "truth.csv"), str(tmp_path / "est.csv"), "--json"]
    assert main(args) == 0
    assert '"n_estimates": 3' in capsys.readouterr().out
    assert main([*args, "--tolerance-ms", "0.001"]) == 2
    err = capsys.readouterr().err
    assert "within 0.001 ms (score --tolerance-ms sets the window)" in err
    assert err.count("\n") == 1
    assert main([*args, "--tolerance-ms", "0.1"]) == 0
    assert '"n_estimates": 3' in capsys.readouterr().out
    halfway = Estimates(e.timestamp_s - 40e-6 + 2.5e-3, *(getattr(e, f) for f in (
        "transmitter", "packet_id", "position_m", "orientation_deg", "method")))  # fmt: skip
    write_estimates_csv(halfway, tmp_path / "est.csv")
    assert main(args) == 2
    assert "no truth row" in capsys.readouterr().err
    write_estimates_csv(e, tmp_path / "est.csv")
    assert main([*args, "--tolerance-ms", "-1"]) == 2
    err = capsys.readouterr().err
    assert "--tolerance-ms must be in [0, 1000] ms" in err and err.count("\n") == 1


def test_unambiguous_tolerance():
    """Just under half the smallest spacing of one transmitter's rows (another
    transmitter's rows at the same times do not narrow it); 1 µs with two rows
    at one time, and where no transmitter has two rows (helper-66: 1 s there
    matched an estimate 0.9 s off)."""
    tr = _truth()
    assert unambiguous_tolerance_s(tr) == pytest.approx(2.5e-3 - 1e-9, abs=1e-9)
    two = Truth(
        np.concatenate([tr.timestamp_s, tr.timestamp_s]),
        np.array([TX] * 10 + ["other"] * 10, object),
        np.concatenate([tr.position_m, tr.position_m]),
        np.concatenate([tr.orientation_deg, tr.orientation_deg]),
    )
    assert unambiguous_tolerance_s(two) == unambiguous_tolerance_s(tr)
    same = Truth(np.zeros(2), np.array([TX, TX], object), tr.position_m[:2], tr.orientation_deg[:2])
    assert unambiguous_tolerance_s(same) == 1e-6
    assert unambiguous_tolerance_s(_truth(1)) == 1e-6


def test_error_stats():
    s = error_stats(np.arange(101, dtype=float))
    assert (s.mean, s.median, s.p95) == (50.0, 50.0, 95.0)
    assert error_stats(np.empty(0)).mean is None


def test_estimates_csv_round_trip(tmp_path):
    tr = _truth()
    e = _est(tr, [0, 3], daz=0.25)
    write_estimates_csv(e, tmp_path / "e.csv")
    back = read_estimates_csv(tmp_path / "e.csv")
    np.testing.assert_allclose(back.timestamp_s, e.timestamp_s, atol=1e-9)
    np.testing.assert_allclose(back.position_m, e.position_m, atol=1e-6)
    np.testing.assert_allclose(back.orientation_deg, e.orientation_deg, atol=1e-6)
    assert list(back.packet_id) == ["0", "3"] and list(back.method) == ["full", "full"]


@pytest.mark.parametrize("with_std", [False, True])
def test_estimates_are_read_from_a_pipe(tmp_path, with_std):
    """``score truth.csv <(...)``: the estimates file is read once, front to back
    (the optional uncertainty columns once made it read the header first, and a
    pipe then had nothing left for the rows)."""
    import os

    tr = _truth()
    e = _est(tr, [0, 3, 5])
    if with_std:
        e = Estimates(
            *(getattr(e, f) for f in ("timestamp_s", "transmitter", "packet_id")),
            e.position_m, e.orientation_deg, e.method,
            position_std_m=np.array([0.1, 0.2, 0.3]), azimuth_std_deg=np.array([1.0, 2.0, 3.0]),
        )  # fmt: skip
    write_estimates_csv(e, tmp_path / "e.csv")
    r, w = os.pipe()  # the file's few hundred bytes fit the pipe's buffer
    os.write(w, (tmp_path / "e.csv").read_bytes())
    os.close(w)
    try:
        back = read_estimates_csv(f"/dev/fd/{r}")
    finally:
        os.close(r)
    assert list(back.packet_id) == ["0", "3", "5"]
    if with_std:
        np.testing.assert_allclose(back.position_std_m, [0.1, 0.2, 0.3])
    else:
        assert back.position_std_m is None


def test_duplicate_truth_and_estimate_rows_are_errors(tmp_path):
    from radiopose.estimates import read_estimates_csv, write_estimates_csv
    from radiopose.packets import read_truth_csv, write_truth_csv

    tr = _truth()
    write_truth_csv(tr, tmp_path / "t.csv")
    lines = (tmp_path / "t.csv").read_text().splitlines(keepends=True)
    (tmp_path / "t2.csv").write_text("".join([*lines, lines[2]]))  # row 2 again, as the last
    with pytest.raises(
        InputError,
        match=rf"t2\.csv:{len(lines) + 1}, column 'timestamp_s': a second truth row.*"
        "first on line 3",
    ):
        read_truth_csv(tmp_path / "t2.csv")
    e = _est(tr, [0, 1, 2])
    write_estimates_csv(e, tmp_path / "e.csv")
    lines = (tmp_path / "e.csv").read_text().splitlines(keepends=True)
    (tmp_path / "e2.csv").write_text("".join([*lines, lines[1]]))
    with pytest.raises(
        InputError, match=r"e2\.csv:5, column 'method': a second estimate.*first on line 2"
    ):
        read_estimates_csv(tmp_path / "e2.csv")


@pytest.mark.parametrize("which", ["truth", "estimates", "packets"])
def test_times_beyond_int64_ns_are_line_errors(tmp_path, which):
    from radiopose.estimates import read_estimates_csv, write_estimates_csv
    from radiopose.packets import (
        Packets,
        read_packets_csv,
        read_truth_csv,
        write_packets_csv,
        write_truth_csv,
    )

    tr = _truth()
    path = tmp_path / f"{which}.csv"
    if which == "truth":
        write_truth_csv(tr, path)
        read = read_truth_csv
    elif which == "estimates":
        write_estimates_csv(_est(tr, [0, 1]), path)
        read = read_estimates_csv
    else:
        n = 2
        write_packets_csv(
            Packets(
                np.array(["0", "1"], dtype=object),
                np.array([0.0, 0.1]),
                np.array(["aa:bb:cc:dd:ee:ff"] * n, dtype=object),
                np.array(["rx1"] * n, dtype=object),
                np.array([-50.0, -51.0]),
            ),
            path,
        )
        read = read_packets_csv
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    row = lines[2].split(",")
    row[header.index("timestamp_s")] = "1e308"
    path.write_text("\n".join([*lines[:2], ",".join(row), *lines[3:]]) + "\n")
    with pytest.raises(InputError, match=rf"{which}\.csv:3, column 'timestamp_s': value 1e308"):
        read(path)


@pytest.mark.parametrize("which", ["truth", "estimates"])
@pytest.mark.parametrize("column", ["x_m", "z_m"])
def test_coordinates_beyond_the_site_limit_are_line_errors(tmp_path, capsys, which, column):
    """A position of 1e300 m (a corrupt file) is refused like any site coordinate
    beyond 1e6 m: it made score print the JSON non-value Infinity and numpy's
    two-line overflow warning (helper-63)."""
    from radiopose.cli import main
    from radiopose.estimates import write_estimates_csv
    from radiopose.packets import write_truth_csv

    tr = _truth()
    write_truth_csv(tr, tmp_path / "truth.csv")
    write_estimates_csv(_est(tr, [0, 1]), tmp_path / "estimates.csv")
    path = tmp_path / f"{which}.csv"
    lines = path.read_text().splitlines()
    row = lines[2].split(",")
    row[lines[0].split(",").index(column)] = "1e300"
    path.write_text("\n".join([*lines[:2], ",".join(row), *lines[3:]]) + "\n")
    assert main(["score", str(tmp_path / "truth.csv"), str(tmp_path / "estimates.csv")]) == 2
    err = capsys.readouterr().err
    assert f"{which}.csv:3, column '{column}': value 1e300 out of range" in err
    assert err.count("\n") == 1


def test_a_packet_transmitter_that_is_not_an_id_is_a_line_error(tmp_path):
    """The contract's transmitter id (no commas or whitespace): a packets.csv row
    breaking it is an error at its line, not an unknown transmitter skipped."""
    from radiopose.packets import Packets, read_packets_csv, write_packets_csv

    path = tmp_path / "packets.csv"
    write_packets_csv(
        Packets(
            np.array(["0", "1", "2"], dtype=object),
            np.array([0.0, 0.1, 0.2]),
            np.array(["phone", "ph one", "phone"], dtype=object),
            np.array(["rx1"] * 3, dtype=object),
            np.array([-50.0, -51.0, -52.0]),
        ),
        path,
    )
    with pytest.raises(
        InputError, match=r"packets\.csv:3, column 'transmitter': not a transmitter"
    ):
        read_packets_csv(path)


def test_a_packet_estimated_twice_in_python_is_an_error():
    """Three estimates of one truth row once gave coverage 3.0 (the CSV reader
    refuses the repeated row; a table built in Python did not)."""
    tr = _truth()
    with pytest.raises(
        InputError, match=r"estimates 1 and 2 of method 'full' are both of truth row 4"
    ):
        score(tr, _est(tr, [3, 3, 3]))
    (s,) = score(tr, _est(tr, [3, 4, 5]))
    assert s.coverage == pytest.approx(0.3)


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda e: e.orientation_deg.__setitem__((1, 0), np.nan), "estimate 2: time, position"),
        (lambda e: e.position_m.__setitem__((0, 2), np.inf), "estimate 1: time, position"),
        (lambda e: e.timestamp_s.__setitem__(2, np.nan), "estimate 3: time, position"),
    ],
)
def test_a_non_finite_estimate_is_an_error_not_a_scipy_traceback(damage, message):
    tr = _truth()
    e = _est(tr, [1, 2, 3])
    damage(e)
    with pytest.raises(InputError, match=message):
        score(tr, e)


@pytest.mark.parametrize("tolerance_s", [np.nan, -1.0, np.inf])
def test_the_tolerance_is_checked(tolerance_s):
    tr = _truth()
    with pytest.raises(InputError, match="tolerance_s"):
        score(tr, _est(tr, [1]), tolerance_s=tolerance_s)
