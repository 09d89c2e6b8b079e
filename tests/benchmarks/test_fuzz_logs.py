"""benchmarks/fuzz_logs.py's parts: the plausible bad messages stay within the input limits
(each is a message a source passes on), the GNSS ones go to surveys with GNSS, and the
table scores runs against their clean survey."""

import io

from agrislam.io.sources.jsonl import read_log
from benchmark_module import load_benchmark
from log_mutations import NEEDS_GNSS, OPERATORS, as_log, operate, survey_lines

# what a source skips as no message at all (else: its time, its place among the records)
MALFORMED = {"not_json", "missing_field", "bad_value", "non_finite", "out_of_bounds"}
MALFORMED |= {"bad_covariance", "too_many_detections", "p_out_of_range", "not_in_schema"}


def test_every_operator_changes_the_log_within_the_input_limits():
    fuzz = load_benchmark("fuzz_logs")
    lines = survey_lines(fuzz.SURVEYS["two robots, gnss, seed 2"])
    for name in OPERATORS:
        changed = operate(lines, name, 1)
        assert [text.decode() for text in changed] != lines, name
        reader = read_log(io.BytesIO(as_log(changed)), strict=False)
        assert list(reader) and not MALFORMED & set(reader.report.skipped), name


def test_changes_put_the_gnss_operators_on_surveys_with_gnss():
    fuzz = load_benchmark("fuzz_logs")
    changes = fuzz.changes(400, 0.5, seed=3)
    operators = [c for c in changes if c[1] != "edit"]
    assert 150 < len(operators) < 250 and {c[1] for c in operators} == set(OPERATORS)
    assert all("gnss" in fuzz.SURVEYS[c[0]] for c in operators if c[1] in NEEDS_GNSS)
    assert {fuzz.operator_of(c) for c in changes if c[1] == "edit"} >= {"edit: a number"}


def test_the_table_scores_each_run_against_its_clean_survey(capsys):
    fuzz = load_benchmark("fuzz_logs")
    clean = {"a": {"mapped": 0.8, "seconds": 1.0}, "b": {"mapped": 1.0, "seconds": 2.0}}

    def run(survey, operator, mapped, outcome="outputs"):
        change = (survey, operator, 0)
        return {"change": change, "outcome": outcome, "mapped": mapped, "seconds": 3.0}

    results = [run("a", "no meta", 0.8), run("b", "no meta", 0.5), run("a", "x", None, "uncaught")]
    results = [{**got, "drawn": False} for got in results]
    assert not fuzz.mapped_table(results, clean)  # 1 of 2 scored runs below 0.9 of clean
    table = capsys.readouterr().out
    assert "no meta                                    2      0  0.75    50%  0.50    3.0x" in table
    assert "1 of 2 (50.0%" in table and "worst changes: no meta (50%)" in table
    assert fuzz.mapped_table(results[:1], clean)
