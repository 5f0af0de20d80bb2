"""Checks a report of a synthetic study (study-synth) against what is known to be true:
every encounter's coded decision equals the participant model's, and every virtual
collision the director reported (read here straight from the recordings) is counted
once. Used by tests/test_study_report.py and `make check-study`."""
import csv
import pathlib
import sys

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1] / "build" / "python"))


def check_study(study_dir, report_dir):
    import lcm
    import portobello
    study_dir, report_dir = pathlib.Path(study_dir), pathlib.Path(report_dir)
    key = lambda r: (r["participant"], r["platform"], r["scenario"], r["stop_line"])
    truth = {key(r): r for r in csv.DictReader(open(study_dir / "truth.csv"))}
    coded = {key(r): r for r in csv.DictReader(open(report_dir / "encounters.csv"))}
    mismatches = [(k, truth[k]["decision"], coded.get(k, {}).get("decision", "missing"), truth[k]["model"])
                  for k in truth if coded.get(k, {}).get("decision") != truth[k]["decision"]]
    mismatches += [(k, "not in truth", coded[k]["decision"], "") for k in coded if k not in truth]
    director = 0
    per_rec = {}
    for r in csv.DictReader(open(study_dir / "study.csv")):
        for ev in lcm.EventLog(str(study_dir / r["recording"]), "r"):
            if ev.channel == "SCENARIO_EVENT" and portobello.scenario_event_t.decode(ev.data).kind == "collision":
                director += 1
                per_rec[r["recording"]] = per_rec.get(r["recording"], 0) + 1
    listed = list(csv.DictReader(open(report_dir / "collisions.csv")))
    listed_per_rec = {}
    for c in listed:
        listed_per_rec[c["recording"]] = listed_per_rec.get(c["recording"], 0) + 1
    in_rows = sum(int(r["collisions"] or 0) for r in coded.values())
    decisions = {}
    for r in coded.values():
        decisions[r["decision"]] = decisions.get(r["decision"], 0) + 1
    return {"encounters": len(coded), "truth": len(truth), "mismatches": mismatches,
            "collisions_director": director,
            "collisions_report": len(listed) if listed_per_rec == per_rec and in_rows == len(listed) else
            f"per recording {listed_per_rec} vs {per_rec}, in encounter rows {in_rows}",
            "decisions": decisions}
