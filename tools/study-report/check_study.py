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


def main():
    """Makes a synthetic study, reports it and checks it; prints a table, writes JSON."""
    import argparse
    import json
    import shutil
    import subprocess
    import time
    ap = argparse.ArgumentParser(prog="check_study.py", description=main.__doc__)
    ap.add_argument("--participants", type=int, default=32)
    ap.add_argument("--work", required=True, help="folder for the study and its report (emptied)")
    ap.add_argument("--json", required=True)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    work = pathlib.Path(a.work)
    shutil.rmtree(work, ignore_errors=True)
    bin_dir = HERE.parents[1] / "build" / "bin"

    def timed(args):
        r0, t0 = __import__("resource").getrusage(__import__("resource").RUSAGE_CHILDREN), time.monotonic()
        subprocess.run([str(x) for x in args], check=True)
        r1 = __import__("resource").getrusage(__import__("resource").RUSAGE_CHILDREN)
        return time.monotonic() - t0, (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)

    synth_wall, synth_cpu = timed([bin_dir / "study-synth", "--out", work / "study", "--participants",
                                   a.participants, "--seed", a.seed])
    rep_wall, rep_cpu = timed([bin_dir / "study-report", "--questionnaire", work / "study" / "questionnaire.csv",
                               "--sessions", work / "study", "--out", work / "report", "--json",
                               work / "report" / "report.json", "--quiet"])
    res = check_study(work / "study", work / "report")
    ok = not res["mismatches"] and res["collisions_director"] == res["collisions_report"] \
        and res["encounters"] == res["truth"]
    rows = [("participants", a.participants), ("recordings", sum(1 for _ in open(work / "study" / "study.csv")) - 1),
            ("encounters coded / true", f"{res['encounters']} / {res['truth']}"),
            ("coded decision != model's", len(res["mismatches"])),
            ("collisions: director / report", f"{res['collisions_director']} / {res['collisions_report']}"),
            ("decisions", ", ".join(f"{k} {v}" for k, v in sorted(res["decisions"].items()))),
            ("study-synth wall / CPU s", f"{synth_wall:.0f} / {synth_cpu:.0f}"),
            ("study-report wall / CPU s", f"{rep_wall:.0f} / {rep_cpu:.0f}"),
            ("result", "PASS" if ok else "FAIL")]
    for k, v in rows:
        print(f"  {k:<32} {v}")
    for m in res["mismatches"][:20]:
        print("  mismatch:", m)
    pathlib.Path(a.json).parent.mkdir(parents=True, exist_ok=True)
    pathlib.Path(a.json).write_text(json.dumps({**res, "mismatches": [list(map(str, m)) for m in res["mismatches"]],
                                                "synth_wall_s": synth_wall, "synth_cpu_s": synth_cpu,
                                                "report_wall_s": rep_wall, "report_cpu_s": rep_cpu,
                                                "participants": a.participants, "pass": ok}, indent=1) + "\n")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
