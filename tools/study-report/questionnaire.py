"""Questionnaire ratings: a strict CSV reader and the per-measure paired comparison."""
import math

import numpy as np

import jzs
from sessions import PLATFORMS, StudyError, csv_rows

COLUMNS = ("participant", "platform", "measure", "value")


def read_questionnaire(path, participants=None):
    """Rows (participant, platform, measure, value or None when unanswered) of a ratings
    CSV. Likert 1-5 integers; an empty value is a missing answer. Every problem raises
    StudyError naming the file and line."""
    out, seen = [], {}
    for line, (p, plat, measure, value) in csv_rows(path, COLUMNS):
        if participants is not None and p not in participants:
            raise StudyError(f"{path}:{line}: unknown participant '{p}' (not in the study folder's study.csv)")
        if plat not in PLATFORMS:
            raise StudyError(f"{path}:{line}: platform '{plat}': expected lab or road")
        if not measure:
            raise StudyError(f"{path}:{line}: empty measure")
        if value == "":
            v = None
        else:
            try:
                v = int(value)
            except ValueError:
                raise StudyError(f"{path}:{line}: value '{value}' is not a whole number (Likert 1-5)")
            if not 1 <= v <= 5:
                raise StudyError(f"{path}:{line}: value {v} outside the Likert scale 1-5")
        key = (p, plat, measure)
        if key in seen:
            raise StudyError(f"{path}:{line}: second rating of {measure} by {p} on {plat} "
                             f"(first on line {seen[key]})")
        seen[key] = line
        out.append((p, plat, measure, v))
    if not out:
        raise StudyError(f"{path}: no ratings")
    return out


def compare_measures(ratings, rscales=(jzs.RSCALE_MEDIUM,), participants=None):
    """Per measure: mean and SD per platform over the participants who answered on both,
    the paired JZS BF10 (road - lab) for each rscale and Jeffreys' category; participants
    with a missing answer are dropped from that measure and counted."""
    by = {}
    for p, plat, m, v in ratings:
        by.setdefault(m, {}).setdefault(p, {})[plat] = v
    out = []
    for m in sorted(by):
        everyone = set(by[m]) | set(participants or ())
        complete = sorted(p for p in everyone
                          if all(by[m].get(p, {}).get(pl) is not None for pl in PLATFORMS))
        lab = np.array([by[m][p]["lab"] for p in complete], float)
        road = np.array([by[m][p]["road"] for p in complete], float)
        res = {"measure": m, "n": len(complete), "dropped": len(everyone) - len(complete),
               "lab_mean": lab.mean() if len(lab) else None, "lab_sd": lab.std(ddof=1) if len(lab) > 1 else None,
               "road_mean": road.mean() if len(road) else None, "road_sd": road.std(ddof=1) if len(road) > 1 else None,
               "lab": lab.tolist(), "road": road.tolist(), "bf10": {}, "category": {}}
        if len(complete) >= 2:
            t, n = jzs.paired_t(road, lab)
            res["t"] = t
            for r in rscales:
                key = f"{r:.6g}"
                if math.isinf(t):        # every difference equal and non-zero: no variance to scale
                    bf = math.inf
                else:
                    bf = jzs.bf10(t, n, r)
                res["bf10"][key] = bf
                res["category"][key] = jzs.jeffreys_category(bf)
        out.append(res)
    return out
