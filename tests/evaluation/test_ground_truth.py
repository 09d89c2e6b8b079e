import numpy as np

from agrislam.evaluation.ground_truth import TruthObjects
from agrislam.records import TruthObject


def test_rows_follow_the_ids_and_a_later_record_replaces_its_row():
    table = TruthObjects()
    assert table.number("d1") == 0  # known from a detection first: a row, no position
    table.add(TruthObject("p0", np.array([1.0, 2.0]), {"colour": "red", "length": 0.3}))
    table.add(TruthObject("d1", np.array([3.0, 4.0]), {"colour": "green"}))
    table.add(TruthObject("p2", np.array([5.0, 6.0]), {"size": "big"}))  # a name met late
    assert table.number("p0") == 1 and len(table) == 3 and table.number("x") == 3
    np.testing.assert_array_equal(table.placed(), [0, 1, 2])  # x has no record
    table.add(TruthObject("p0", np.array([1.5, 2.5]), {"colour": "blue", "length": 0.4}))
    rows = np.array([0, 1, 2, 3])
    np.testing.assert_array_equal(table.xy(rows[:3]), [[3, 4], [1.5, 2.5], [5, 6]])
    assert table.text("colour", rows).tolist() == ["green", "blue", None, None]
    assert table.text("size", rows).tolist() == [None, None, "big", None]
    assert table.text("unknown", rows).tolist() == [None] * 4
    np.testing.assert_array_equal(table.values("length", rows), [np.nan, 0.4, np.nan, np.nan])
    np.testing.assert_array_equal(table.values("unknown", rows[:2]), [np.nan, np.nan])


def test_a_table_of_records_holds_what_the_records_say():
    rng = np.random.default_rng(3)
    records = [
        TruthObject(f"p{i % 150}", rng.normal(size=2), {"kind": str(rng.integers(4))})
        for i in range(200)  # 50 ids come twice: their second record counts
    ]
    table = TruthObjects.of(records)
    latest = {r.id: r for r in records}
    rows = np.array([table.numbers[i] for i in latest])
    np.testing.assert_array_equal(table.xy(rows), [r.xy for r in latest.values()])
    assert table.text("kind", rows).tolist() == [r.attributes["kind"] for r in latest.values()]
