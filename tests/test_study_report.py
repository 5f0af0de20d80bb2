"""study-report: Bayes factors against R BayesFactor, questionnaires, recordings, the report.

The synthetic study here is small (3 participants, one per participant model, both
orders, both platforms, the five shipped scenarios); `make check-study` runs the full
32-participant one with the same checks (tools/study-report/check_study.py).
"""
import csv
import json
import math
import pathlib
import shutil
import sys

import pytest

from conftest import BIN, ROOT, run

sys.path.insert(0, str(ROOT / "tools" / "study-report"))
import jzs  # noqa: E402
from check_study import check_study  # noqa: E402

DATA = ROOT / "tests" / "data" / "bayes_factor_jzs"
REPORT = BIN / "study-report"
SYNTH = BIN / "study-synth"


# ---------------------------------------------------------------- Bayes factors
def test_bf10_matches_bayesfactor_grid():
    rows = list(csv.DictReader(open(DATA / "jzs_bf10_grid.csv")))
    assert len(rows) == 24
    worst = 0.0
    for r in rows:
        bf = jzs.bf10(float(r["t"]), int(r["n"]), float(r["rscale"]))
        worst = max(worst, abs(bf - float(r["BF10"])) / float(r["BF10"]))
    # measured 3.5e-10: the reference values carry 10 significant digits (target 1e-5)
    assert worst < 1e-9, worst


def test_sleep_paired_example():
    # Cushny & Peebles' sleep data (R's `sleep`): extra hours of sleep, drug 1 vs drug 2,
    # the same 10 patients; ttestBF(paired = TRUE) prints 17.25888
    drug1 = [0.7, -1.6, -0.2, -1.2, -0.1, 3.4, 3.7, 0.8, 0.0, 2.0]
    drug2 = [1.9, 0.8, 1.1, 0.1, -0.1, 4.4, 5.5, 1.6, 4.6, 3.4]
    t, n = jzs.paired_t(drug1, drug2)
    assert n == 10 and abs(t - -4.062127683) < 1e-8
    assert round(jzs.bf10(t, n), 3) == 17.259
    assert jzs.jeffreys_category(jzs.bf10(t, n)) == "strong evidence for H1"


@pytest.mark.parametrize("t,n,r", [(0.0, 5, 1.0), (2.5, 20, 0.5), (4.06, 10, 1.0), (8.0, 60, math.sqrt(2))])
def test_other_rscales_agree_with_the_integral_in_g(t, n, r):
    # eq. 1 of Rouder et al. integrated directly over g (an independent form of the sum)
    from scipy import integrate
    nu = n - 1
    f = lambda g: ((1 + n * g * r * r) ** -0.5 * (1 + t * t / ((1 + n * g * r * r) * nu)) ** (-(nu + 1) / 2)
                   * (2 * math.pi) ** -0.5 * g ** -1.5 * math.exp(-1 / (2 * g)))
    num = sum(integrate.quad(f, a, b, epsabs=0, epsrel=1e-12, limit=500)[0]
              for a, b in [(0, 0.1), (0.1, 10), (10, 1e4), (1e4, math.inf)])
    ref = num / (1 + t * t / nu) ** (-(nu + 1) / 2)
    assert abs(jzs.bf10(t, n, r) - ref) / ref < 1e-8


def test_jeffreys_categories():
    cases = {150: "extreme evidence for H1", 50: "very strong evidence for H1", 20: "strong evidence for H1",
             5: "moderate evidence for H1", 2: "anecdotal evidence for H1", 1: "no evidence",
             0.5: "anecdotal evidence for H0", 0.2: "moderate evidence for H0", 0.05: "strong evidence for H0",
             0.02: "very strong evidence for H0", 0.001: "extreme evidence for H0"}
    for bf, label in cases.items():
        assert jzs.jeffreys_category(bf) == label, bf


# ---------------------------------------------------------------- questionnaires
def _write(path, text):
    path.write_text(text)
    return path


def test_questionnaire_alone_with_missing_answers(tmp_path):
    rows = ["participant,platform,measure,value"]
    lab = [2, 3, 2, 3, 2, 4, 3, 2]
    road = [4, 4, 3, 5, 4, 5, 4, 3]
    for i, (a, b) in enumerate(zip(lab, road)):
        rows += [f"p{i},lab,realism,{a}", f"p{i},road,realism,{b if i != 3 else ''}"]
    rows += ["p9,lab,realism,3"]     # never rated on the road
    q = _write(tmp_path / "q.csv", "\n".join(rows) + "\n")
    out = tmp_path / "rep"
    run([REPORT, "--questionnaire", q, "--out", out, "--json", tmp_path / "r.json", "--rscale", "0.7071067811865476",
         "--rscale", "1", "--quiet"])
    doc = json.loads((tmp_path / "r.json").read_text())
    m = doc["measures"][0]
    assert m["measure"] == "realism" and m["n"] == 7 and m["dropped"] == 2
    keep = [i for i in range(8) if i != 3]
    t, n = jzs.paired_t([road[i] for i in keep], [lab[i] for i in keep])
    assert abs(m["bf10"]["0.707107"] - jzs.bf10(t, n)) < 1e-9 * jzs.bf10(t, n)
    assert abs(m["bf10"]["1"] - jzs.bf10(t, n, 1.0)) < 1e-9 * jzs.bf10(t, n, 1.0)
    table = list(csv.DictReader(open(out / "bayes_factors.csv")))
    assert table[0]["dropped"] == "2" and table[0]["category_r0.707107"] == m["category"]["0.707107"]


@pytest.mark.parametrize("body,where", [
    ("participant,platform,measure\np1,lab,realism\n", "q.csv:1: missing column 'value'"),
    ("participant,platform,measure,value\np1,lab,realism,6\n", "q.csv:2: value 6 outside the Likert scale 1-5"),
    ("participant,platform,measure,value\np1,lab,realism,3\np1,road,realism,0\n", "q.csv:3: value 0 outside"),
    ("participant,platform,measure,value\np1,lab,realism,3.5\n", "q.csv:2: value '3.5' is not a whole number"),
    ("participant,platform,measure,value\np1,car,realism,3\n", "q.csv:2: platform 'car'"),
    ("participant,platform,measure,value\np1,lab,realism,3\n\np1,lab,realism,4\n", "q.csv:4: second rating"),
    ("participant,platform,measure,value\np1,lab,realism\n", "q.csv:2: 3 fields"),
    ("", "q.csv:1: empty file"),
])
def test_bad_questionnaire_names_file_and_line(tmp_path, body, where):
    q = _write(tmp_path / "q.csv", body)
    p = run([REPORT, "--questionnaire", q, "--out", tmp_path / "rep", "--quiet"], check=False)
    assert p.returncode == 1 and where in p.stderr, p.stderr
    assert not (tmp_path / "rep" / "report.html").exists()


def test_unknown_participant_and_bad_study_folder(tmp_path):
    study = tmp_path / "study"
    study.mkdir()
    _write(study / "study.csv", "participant,order,platform,recording\np1,lab_first,lab,p1.lcm\n"
                                "p1,lab_first,road,p1_road.lcm\n")
    q = _write(tmp_path / "q.csv", "participant,platform,measure,value\np1,lab,realism,3\np7,lab,realism,3\n")
    p = run([REPORT, "--questionnaire", q, "--sessions", study, "--out", tmp_path / "rep", "--quiet"], check=False)
    assert p.returncode == 1 and "q.csv:3: unknown participant 'p7'" in p.stderr, p.stderr
    _write(study / "study.csv", "participant,order,platform,recording\np1,sideways,lab,p1.lcm\n")
    p = run([REPORT, "--questionnaire", q, "--sessions", study, "--out", tmp_path / "rep", "--quiet"], check=False)
    assert p.returncode == 1 and "study.csv:2: order 'sideways'" in p.stderr, p.stderr
    _write(study / "study.csv", "participant,platform,recording\np1,lab,p1.lcm\n")
    p = run([REPORT, "--questionnaire", q, "--sessions", study, "--out", tmp_path / "rep", "--quiet"], check=False)
    assert p.returncode == 1 and "study.csv:1: missing column 'order'" in p.stderr, p.stderr


# ---------------------------------------------------------------- synthetic sessions
@pytest.fixture(scope="module")
def synth(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth")
    run([SYNTH, "--out", out, "--participants", 3, "--seed", 3])
    return out


@pytest.fixture(scope="module")
def synth_report(synth, tmp_path_factory):
    rep = tmp_path_factory.mktemp("rep")
    run([REPORT, "--questionnaire", synth / "questionnaire.csv", "--sessions", synth, "--out", rep,
         "--json", rep / "r.json", "--quiet"])
    return rep


def test_synthetic_sessions_decisions_and_collisions(synth, synth_report):
    rep = synth_report
    res = check_study(synth, rep)
    # 3 participants x 2 platforms x (4 single-encounter files + the 4-encounter study)
    assert res["encounters"] == 3 * 2 * 8
    assert res["mismatches"] == [], res["mismatches"][:5]
    assert res["collisions_director"] == res["collisions_report"]
    assert res["collisions_director"] > 0          # impatient presses do run into pedestrians
    assert set(res["decisions"]) >= {"at_kerb", "cleared", "not_crossing"}
    doc = json.loads((rep / "r.json").read_text())
    assert len(doc["encounters"]) == res["encounters"] and doc["skipped"] == []


def test_report_renders_in_chromium(synth_report, tmp_path):
    from browser import assert_not_blank, screenshot
    rep = synth_report
    page = (rep / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 4       # the figures travel inside the page
    assert "src=\"http" not in page and "href=\"http" not in page
    for name in ("bayes_factors", "rating_distributions", "comparison_histograms", "encounters", "decisions",
                 "collisions"):
        assert (rep / f"{name}.csv").exists()
    png = screenshot(rep / "report.html", tmp_path / "report.png", size=(1280, 1800))
    assert_not_blank(png)


def test_missing_and_damaged_recordings_are_skipped(synth, tmp_path):
    study = tmp_path / "study"
    shutil.copytree(synth, study)
    rows = list(csv.DictReader(open(study / "study.csv")))[:4]      # four recordings are enough here
    with open(study / "study.csv", "w", newline="") as f:
        w = csv.DictWriter(f, list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    q = (study / "questionnaire.csv").read_text().splitlines()
    (study / "questionnaire.csv").write_text("\n".join(l for l in q if not l.startswith(("p02", "p03"))) + "\n")
    cut = study / rows[0]["recording"]           # the recorder died mid-event
    cut.write_bytes(cut.read_bytes()[:-1000])
    (study / rows[1]["recording"]).unlink()
    junk = study / rows[2]["recording"]          # bytes that are no event
    junk.write_bytes(b"not an event" + junk.read_bytes())
    rep = tmp_path / "rep"
    p = run([REPORT, "--questionnaire", study / "questionnaire.csv", "--sessions", study, "--out", rep,
             "--json", rep / "r.json", "--quiet"])
    doc = json.loads((rep / "r.json").read_text())
    reasons = {s["recording"]: s["reason"] for s in doc["skipped"]}
    assert set(reasons) == {rows[k]["recording"] for k in range(3)}
    assert "runs past the end of the file" in reasons[rows[0]["recording"]], reasons
    assert "missing" in reasons[rows[1]["recording"]]
    assert "byte 0: bad sync word" in reasons[rows[2]["recording"]]
    assert p.stderr.count("skipped") == 3
    used = {e["recording"] for e in doc["encounters"]}
    assert not used & set(reasons) and rows[3]["recording"] in used
    assert "Skipped recordings" in (rep / "report.html").read_text()


# ---------------------------------------------------------------- a hand-made recording
def _handmade_recording(path, press_s, collide=False):
    """The car rests 4.04 m behind sl01 (its rest point) from t = 0 to 20 s; cw01's main
    pedestrian walks up to the kerb (off it until 3 s), stands at the kerb until 5 s,
    crosses until 14 s (1.4 m/s), then walks on. One press at press_s."""
    import numpy as np
    import portobello
    from sessions import _frame
    from study_synth import UTIME0, write_log
    sl = {"xy": [48.23, -3.51], "yaw_deg": -2.08}
    cw = {"center": [51.79, -1.88], "yaw_deg": -2.08}
    along, _ = _frame(sl)
    _, across = _frame(cw)
    rest = np.array(sl["xy"]) - along * (4.54 - 1.04 + 0.5)
    ev = []

    def ped(t):
        a = (-8.5 - (3 - t) * 1.4 if t < 3 else -6.3 if t < 5 else
             -6.3 + (t - 5) * 12.6 / 9 if t < 14 else 6.3 + min(t - 14, 2) * 1.4)
        return np.array(cw["center"]) + across * a

    for i in range(-200, 2500):                  # poses at 100 Hz: arriving, 20 s at rest, leaving
        t = i * 0.01
        v = 5.0 if t < 0 else 0.0 if t < 20 else 5.0
        xy = rest + along * (5.0 * t if t < 0 else 0 if t < 20 else 5.0 * (t - 20))
        p = portobello.pose_t()
        p.utime = UTIME0 + round(t * 1e6)
        p.position = [xy[0], xy[1], 0.0]
        yaw = math.radians(sl["yaw_deg"])
        p.orientation = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
        p.velocity = [v * along[0], v * along[1], 0.0]
        p.angular_velocity = [0.0] * 3
        p.covariance = [0.0] * 36
        p.status, p.source, p.match_score = 1, 1, float("nan")
        ev.append((p.utime, "POSE", p.encode()))
    for i in range(-60, 1500):                   # AGENTS at 60 Hz, as the director
        t = i / 60
        a = portobello.agents_t()
        a.utime, a.scenario, a.nagents = UTIME0 + round(t * 1e6), "cw01_look_and_cross", 1
        g = portobello.agent_t()
        g.id, g.kind, g.model = "ped_a_main", "pedestrian", "m"
        g.position = list(ped(t)) + [0.0]
        g.yaw_rad, g.velocity, g.animation, g.animation_phase = 0.0, [0.0] * 3, "walk", 0.0
        g.in_render_range, g.distance_m = True, 10.0
        a.agents = [g]
        ev.append((a.utime, "AGENTS", a.encode()))

    def scen(t, kind, agent=""):
        e = portobello.scenario_event_t()
        e.utime, e.scenario, e.kind, e.event_id, e.agent_id = UTIME0 + round(t * 1e6), "cw01_look_and_cross", kind, \
            kind, agent
        e.vehicle = portobello.pose_t()
        e.vehicle.orientation = [1.0, 0, 0, 0]
        e.vehicle.covariance = [0.0] * 36
        e.agent_position, e.detail = [0.0] * 3, ""
        return (e.utime, "SCENARIO_EVENT", e.encode())
    ev += [scen(-1.0, "trigger"), scen(3.0, "mark", "ped_a_main")]
    if collide:
        ev.append(scen(21.0, "collision", "ped_a_main"))
    from study_synth import press_msg
    ev.append((UTIME0 + round(press_s * 1e6), "PARTICIPANT_INPUT", press_msg(UTIME0 + round(press_s * 1e6))))
    ev.sort(key=lambda e: e[0])
    write_log(path, ev)


def test_handmade_recordings_code_every_state(tmp_path):
    sys.path.insert(0, str(BIN.parents[0] / "python"))
    cases = {"approaching": 1.0, "at_kerb": 4.0, "on_crosswalk": 9.5, "cleared": 16.0}
    study = tmp_path / "study"
    study.mkdir()
    lines = ["participant,order,platform,recording"]
    for k, (state, t) in enumerate(cases.items()):
        _handmade_recording(study / f"{state}.lcm", t, collide=state == "on_crosswalk")
        lines.append(f"h{k},lab_first,lab,{state}.lcm")
    (study / "study.csv").write_text("\n".join(lines) + "\n")
    q = _write(tmp_path / "q.csv", "participant,platform,measure,value\nh0,lab,realism,3\nh0,road,realism,4\n")
    rep = tmp_path / "rep"
    run([REPORT, "--questionnaire", q, "--sessions", study, "--out", rep, "--quiet"])
    rows = {r["recording"]: r for r in csv.DictReader(open(rep / "encounters.csv"))}
    for state, t in cases.items():
        r = rows[f"{state}.lcm"]
        assert r["decision"] == state, (state, r)
        assert abs(float(r["press_after_stop_s"]) - t) < 0.011
        assert abs(float(r["arrival_offset_s"]) - 3.0) < 0.011
        # stepped off the crosswalk (6 m across its centre) at 5 + 12.3 / 1.4 s; the
        # track is read at 20 Hz, so the step-off is seen up to 50 ms late
        late = (t - float(r["press_after_clear_s"])) - (5 + 12.3 / 1.4)
        assert 0 <= late <= 0.051, r
        assert r["cooperative"] == ("yes" if state == "cleared" else "no")
        assert r["collisions"] == ("1" if state == "on_crosswalk" else "0")
    # closest approach: the pedestrian crosses ahead of the resting car's front bumper
    # (0.5 m behind sl01) along the crosswalk's centre, minus its 0.3 m radius
    yaw = math.radians(-2.08)
    gap = (51.79 - 48.23) * math.cos(yaw) + (-1.88 + 3.51) * math.sin(yaw) + 0.5 - 0.3
    for r in rows.values():
        assert abs(float(r["min_distance_m"]) - gap) < 0.01, (r["min_distance_m"], gap)
        assert r["near_miss"] == ("no" if gap >= 1.0 else "yes")


def test_mutated_inputs_give_named_errors_only(tmp_path):
    """A small in-process fuzz: 600 random mutations of a questionnaire, a study.csv and
    a recording are read; each either parses or raises StudyError naming the file (a
    recording's StudyError names a byte offset), never any other exception."""
    import random
    from questionnaire import read_questionnaire
    from sessions import StudyError, read_lcm_log, read_study
    from study_synth import UTIME0, press_msg, write_log
    rng = random.Random(5)
    q = b"participant,platform,measure,value\np1,lab,realism,3\np1,road,realism,4\np2,lab,realism,\n"
    study = b"participant,order,platform,recording\np1,lab_first,lab,a.lcm\np1,lab_first,road,b.lcm\n"
    write_log(tmp_path / "r.lcm", [(UTIME0 + k, "PARTICIPANT_INPUT", press_msg(UTIME0 + k)) for k in range(5)])
    rec = (tmp_path / "r.lcm").read_bytes()

    def mutate(b):
        b = bytearray(b)
        for _ in range(rng.randint(1, 4)):
            op, i = rng.randrange(3), rng.randrange(len(b) + 1)
            if op == 0 and i < len(b):
                b[i] = rng.randrange(256)
            elif op == 1:
                b[i:i] = bytes([rng.choice(b",\n\"3x\xff\0")])
            elif i < len(b):
                del b[i]
        return bytes(b)

    outcomes = {"ok": 0, "error": 0}
    for k in range(200):
        f = tmp_path / "q.csv"
        f.write_bytes(mutate(q))
        d = tmp_path / f"s{k}"
        d.mkdir()
        (d / "study.csv").write_bytes(mutate(study))
        (tmp_path / "m.lcm").write_bytes(mutate(rec))
        for path, read in ((f, lambda: read_questionnaire(f, {"p1", "p2"})), (d / "study.csv", lambda: read_study(d)),
                           (tmp_path / "m.lcm", lambda: read_lcm_log(tmp_path / "m.lcm"))):
            try:
                read()
                outcomes["ok"] += 1
            except StudyError as e:
                assert str(path) in str(e), e
                outcomes["error"] += 1
            except UnicodeDecodeError:
                raise AssertionError(f"{path}: undecodable bytes escaped as UnicodeDecodeError")
    assert outcomes["ok"] > 0 and outcomes["error"] > 0, outcomes
