"""study-report: from session recordings and questionnaires to the twinned-study report."""
import argparse
import json
import math
import pathlib
import sys

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT / "build" / "python"))

import yaml  # noqa: E402

import jzs  # noqa: E402
from questionnaire import compare_measures, read_questionnaire  # noqa: E402
from sessions import Site, StudyError, analyse_study  # noqa: E402

USAGE = """\
study-report --questionnaire Q.csv [--sessions STUDY_DIR] --out REPORT_DIR [--json FILE]

Turns a twinned study (the same scenarios in the lab twin and on the road) into a report:
REPORT_DIR/report.html (one self-contained page: Bayes factor table, rating distributions,
direct-comparison histograms, decisions per scenario, collisions, timing offsets) and the
CSVs behind it (bayes_factors, rating_distributions, comparison_histograms, encounters,
decisions, collisions, skipped_recordings).

Q.csv: participant,platform,measure,value (platform lab|road, value Likert 1-5, empty =
unanswered). STUDY_DIR/study.csv: participant,order,platform,recording (order lab_first|
road_first; recording an LCM log relative to STUDY_DIR, one row per recording). Missing
or damaged recordings are reported and skipped. Bad input exits 1 naming file and line.
"""


def main(argv=None):
    ap = argparse.ArgumentParser(prog="study-report", usage=USAGE, description=None, add_help=True)
    ap.add_argument("--questionnaire", required=True, help="ratings CSV")
    ap.add_argument("--sessions", help="study folder with study.csv and the recordings")
    ap.add_argument("--out", required=True, help="report folder (created)")
    ap.add_argument("--json", help="write the results as JSON here too")
    ap.add_argument("--rscale", action="append", type=float,
                    help="Cauchy prior scale(s) of the Bayes factor (repeatable; default sqrt(2)/2)")
    ap.add_argument("--site", default=str(ROOT / "maps" / "default"), help="site folder (route, scenarios)")
    ap.add_argument("--vehicle", default=str(ROOT / "vehicles" / "prius2017.yaml"), help="vehicle file")
    ap.add_argument("--pose-channel", help="vehicle pose channel (default POSE, else GROUND_TRUTH)")
    ap.add_argument("--title", default="Twinned study: lab vs road")
    ap.add_argument("--quiet", action="store_true", help="no progress")
    a = ap.parse_args(argv)
    rscales = a.rscale or [jzs.RSCALE_MEDIUM]
    for r in rscales:
        if not (r > 0 and math.isfinite(r)):
            print(f"study-report: --rscale must be positive, got {r}", file=sys.stderr)
            return 2
    out = pathlib.Path(a.out)
    try:
        participants, rows, collisions, skipped, listed = {}, [], [], [], 0
        if a.sessions:
            try:
                site = Site(a.site, a.vehicle)
            except (OSError, KeyError, TypeError, yaml.YAMLError) as e:
                raise StudyError(f"site {a.site} or vehicle {a.vehicle}: cannot read: {type(e).__name__}: {e}")
            participants, rows, collisions, skipped, listed = analyse_study(pathlib.Path(a.sessions), site,
                                                                    a.pose_channel, not a.quiet)
        ratings = read_questionnaire(a.questionnaire, participants if a.sessions else None)
    except StudyError as e:
        print(f"study-report: {e}", file=sys.stderr)
        return 1
    for s in skipped:
        print(f"study-report: skipped {s['reason']}", file=sys.stderr)
    from report import write_report     # matplotlib: only once the input is known good
    measures = compare_measures(ratings, rscales, participants if a.sessions else None)
    out.mkdir(parents=True, exist_ok=True)
    nparts = len(participants) or len({r[0] for r in ratings})
    page, bf_rows, dec_rows = write_report(out, a.title, measures, rscales, rows, collisions, skipped,
                                           {"participants": nparts, "recordings": listed - len(skipped),
                                            "questionnaire": pathlib.Path(a.questionnaire).name})
    if a.json:
        def clean(v):
            if isinstance(v, float) and not math.isfinite(v):
                return str(v)
            if isinstance(v, dict):
                return {k: clean(x) for k, x in v.items()}
            if isinstance(v, list):
                return [clean(x) for x in v]
            return v
        doc = {"participants": participants, "rscales": rscales,
               "measures": [{k: m[k] for k in m if k not in ("lab", "road")} for m in measures],
               "encounters": rows, "decisions": dec_rows, "collisions": collisions, "skipped": skipped}
        pathlib.Path(a.json).write_text(json.dumps(clean(doc), indent=1) + "\n")
    if not a.quiet:
        print(f"study-report: {len(measures)} measures, {len(rows)} encounters, {len(collisions)} collisions, "
              f"{len(skipped)} recordings skipped -> {page}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
