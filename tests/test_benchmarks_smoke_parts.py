"""The benchmarks that execute skills on work pieces, the KU Leuven object's CAD and parts changed behind the
controller's back: each ``--smoke`` run exits 0 and prints numbers from that run, writing nothing (helpers:
test_benchmarks_smoke.py; a file of its own so that ``pytest -n 2 --dist loadfile`` runs it beside the others)."""

from __future__ import annotations

from test_benchmarks_smoke import finite, numbers, run_smoke, table, tables


def test_contours_benchmark_smoke():
    """The case as taught, with every controller: a cell per controller with its force errors and contact share."""
    out = run_smoke("bench_contours.py")
    rows = table(out, "unknown change")
    assert [row[0] for row in rows] == ["as taught"]
    for cell in rows[0][1:]:
        rms, peak, contact = numbers(cell)[:3]
        assert 0 < rms <= peak and 0 <= contact <= 100, cell


def test_verdicts_benchmark_smoke():
    """The flat-table slide as taught, fixed and following: the counts row and a table row, both settings judged."""
    out = run_smoke("bench_verdicts.py")
    (counts,) = table(out, "group")
    assert counts[0] == "tuned" and numbers(counts[1])[0] == 2, counts
    (row,) = table(out, "skill")
    assert row[:3] == ["slide_flat", "as taught", "tuned"] and all("pass" in cell for cell in row[3:]), row


def test_real_skills_benchmark_smoke():
    """One KU Leuven trial at its surface and 2 cm higher; the sentence counts the table's rows."""
    out = run_smoke("bench_real_skills.py")
    rows = table(out, "trial | unknown shift")
    assert [(row[0], row[1]) for row in rows] == [("contour_a_1", "+0 cm"), ("contour_a_1", "+2 cm")]
    done = sum(row[2] == "done" for row in rows)
    assert f"{done} of 2 executions finished" in out
    worst = max(float(row[4]) for row in rows)
    assert f"worst {worst:.2f} %" in out


def test_work_piece_benchmark_smoke():
    """One flat case, one cylinder, one KU Leuven trial, each learned both ways; the floor sentence from the rows."""
    out = run_smoke("bench_work_piece.py")
    flat = table(out, "case | learned as | ideal table")
    assert len(flat) == 2 and flat[1][1].endswith("(forced)")
    added = max(numbers(row[4])[0] for row in flat)
    assert f"The measured piece adds at most {added:+.2f} % RMS" in out
    assert len(table(out, "case | learned as | true cylinder")) == 2
    ku = table(out, "case | learned as | measured | rebuilt")
    assert [row[0] for row in ku] == ["contour_a_1", "contour_a_1"]
    assert all(finite(*numbers(row[2]), *numbers(row[3])) for row in ku)


def test_kuleuven_cad_benchmark_smoke():
    """The ridge on one exact prism and on the KU object's pieces, and one KU Leuven trial on its CAD."""
    out = run_smoke("bench_kuleuven_cad.py", timeout_s=400.0)
    ridge = table(out, "geometry | convex parts")
    assert len(ridge) == 2 and ridge[0][0] == "one exact convex prism" and int(ridge[1][1]) > 1
    exact, pieces = float(ridge[0][3]), float(ridge[1][3])
    assert f"holds the force to {exact:.2f} % RMS" in out and f"to {pieces:.2f} %:" in out
    runs = table(out, "trial | work piece")
    assert {row[0] for row in runs} == {"contour_a_1"}


def test_kuleuven_truth_benchmark_smoke():
    """The four recordings registered to the CAD: a row each, distances in millimetres."""
    out = run_smoke("bench_kuleuven_truth.py")
    rows = table(out, "trial | samples")
    assert len(rows) == 4
    for row in rows:
        assert int(row[1]) > 500 and finite(*numbers(row[2])) and 0 < numbers(row[2])[0] < 50, row


def test_mujoco_loop_benchmark_smoke():
    """The table and the KU Leuven CAD in both engines: five rows, each with a real-time factor, and the loops on the
    table pressing the 15 N they push with (the CAD's arm touches nothing)."""
    out = run_smoke("bench_mujoco_loop.py")
    rows = table(out, "world | loop")
    assert len(rows) == 5
    for row in rows:
        rtf = numbers(row[2])
        assert finite(*rtf) and rtf[0] > 0, row
        force = numbers(row[4])[0]
        assert abs(force - (15.0 if row[0].startswith("table") else 0.0)) < 0.1, row
    assert "Through the robot interface the MuJoCo loop runs at" in out


def test_engines_benchmark_smoke():
    """The first teacher case on both engines: two rows, both done and passed, MuJoCo's true RMS within 2 points of
    PyBullet's; the first perturbation (the flat table as taught) passed and judged done on both, counted as agreeing;
    the first KU Leuven case done on both engines in the same table format; and the MuJoCo loop's real-time factor
    beside the bare loop's."""
    out = run_smoke("bench_engines.py", timeout_s=360.0)
    teacher, kuleuven = tables(out, "case | engine | final")
    assert [row[1] for row in teacher] == ["pybullet", "mujoco"]
    for row in teacher:
        assert row[2] == "done" and row[7] == "pass", row
        assert finite(*numbers(row[3])) and numbers(row[3])[0] < 3.0, row  # true RMS, % of the taught force
    [difference], [ku_difference] = tables(out, "case | Δ true RMS")
    assert abs(numbers(difference[1])[0]) <= 2.0 and difference[3] == "yes" and difference[4] == "yes", difference
    [pair] = table(out, "skill | perturbation | PyBullet")
    assert pair[:2] == ["slide_flat", "as taught"] and pair[4:7] == ["yes", "done", "done"], pair
    for cell in pair[2:4]:
        assert cell.endswith(", pass") and numbers(cell)[0] < 3.0, cell
    assert "Verdicts agree between the engines on 1 of 1 perturbations" in out
    assert [(row[0].startswith("KU contour_a_1"), row[1], row[2]) for row in kuleuven] == [
        (True, "pybullet", "done"),
        (True, "mujoco", "done"),
    ]
    for row in kuleuven:
        assert finite(*numbers(row[3])) and numbers(row[3])[0] < 10.0, row  # true RMS on the rebuilt work piece
    assert abs(numbers(ku_difference[1])[0]) <= 2.0, ku_difference
    [loop, bare, _] = table(out, "loop | real-time factor")
    assert numbers(loop[1])[0] > 0 and numbers(bare[1])[0] > 0
    assert "of the bare MuJoCo loop's real-time factor" in out
