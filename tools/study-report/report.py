"""The twinned-study report: CSV tables, figures and one self-contained HTML page."""
import base64
import csv
import html
import io
import math

import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from sessions import ENCOUNTER_COLUMNS, PLATFORMS, STATES  # noqa: E402

COLOURS = {"lab": "#4C72B0", "road": "#DD8452"}
STATE_COLOURS = {"approaching": "#c44e52", "at_kerb": "#dd8452", "on_crosswalk": "#8c1c13",
                 "cleared": "#55a868", "not_crossing": "#8da0cb", "no_press": "#bbbbbb", "no_stop": "#555555"}


def write_csv(path, rows, columns):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({c: _fmt(r.get(c)) for c in columns})


def _fmt(v):
    if v is None:
        return ""
    if isinstance(v, float):
        return "inf" if math.isinf(v) else f"{v:.6g}"
    return v


def _png(fig):
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def _small_multiples(measures, height, draw):
    """One panel per measure, four to a row; draw(ax, measure) fills each."""
    n = len(measures)
    cols = min(n, 4)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, height * rows), squeeze=False)
    for ax, m in zip(axes.flat, measures):
        draw(ax, m)
        ax.set_title(m["measure"], fontsize=10)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    axes.flat[0].set_ylabel("participants")
    return fig, axes


def rating_distributions(measures):
    """The paper's first kind: per measure, how many gave each rating, lab beside road."""
    def draw(ax, m):
        for k, pl in enumerate(PLATFORMS):
            counts = [m[pl].count(v) for v in range(1, 6)]
            ax.bar(np.arange(1, 6) + (k - 0.5) * 0.38, counts, 0.38, color=COLOURS[pl], label=pl)
        ax.set_xticks(range(1, 6))
        ax.set_xlabel("rating")
    fig, axes = _small_multiples(measures, 2.6, draw)
    axes.flat[0].legend(fontsize=8)
    fig.tight_layout()
    return _png(fig)


def comparison_histograms(measures):
    """The paper's second kind: per measure, the histogram of road - lab per participant."""
    def draw(ax, m):
        d = np.array(m["road"]) - np.array(m["lab"])
        counts = [int(np.sum(d == v)) for v in range(-4, 5)]
        ax.bar(range(-4, 5), counts, 0.8, color=["#4C72B0" if v < 0 else "#999999" if v == 0 else "#DD8452"
                                                for v in range(-4, 5)])
        ax.set_xticks(range(-4, 5))
        ax.set_xlabel("road - lab")
    fig, _ = _small_multiples(measures, 2.4, draw)
    fig.tight_layout()
    return _png(fig)


def decisions_figure(table, groups):
    """Stacked bars: the pedestrian's state at Proceed, per scenario encounter x platform x order."""
    fig, ax = plt.subplots(figsize=(max(6, 0.55 * len(groups) + 2), 4))
    bottom = np.zeros(len(groups))
    states = [s for s in STATES + ("no_press", "no_stop") if any(table[g].get(s) for g in groups)]
    for s in states:
        v = np.array([table[g].get(s, 0) for g in groups], float)
        ax.bar(range(len(groups)), v, bottom=bottom, color=STATE_COLOURS[s], label=s)
        bottom += v
    ax.set_xticks(range(len(groups)))
    ax.set_xticklabels([f"{g[0]}/{g[1]}\n{g[2]} {g[3].replace('_first', ' 1st')}" for g in groups],
                       rotation=90, fontsize=7)
    ax.set_ylabel("encounters")
    ax.legend(fontsize=8, bbox_to_anchor=(1.01, 1), loc="upper left")
    fig.tight_layout()
    return _png(fig)


def offsets_figure(rows):
    fig, ax = plt.subplots(figsize=(6, 3))
    for pl in PLATFORMS:
        v = [r["arrival_offset_s"] for r in rows if r["platform"] == pl and r.get("arrival_offset_s") is not None]
        if v:
            ax.hist(v, bins=20, alpha=0.6, color=COLOURS[pl], label=f"{pl} (n={len(v)})")
    ax.set_xlabel("pedestrian at mark - car at rest (s)")
    ax.set_ylabel("encounters")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return _png(fig)


def _table(rows, columns, cls=""):
    head = "".join(f"<th>{html.escape(c)}</th>" for c in columns)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(_fmt(r.get(c))))}</td>" for c in columns) + "</tr>"
                   for r in rows)
    return f'<table class="{cls}"><tr>{head}</tr>{body}</table>'


def decisions_table(rows):
    groups, table = [], {}
    for r in rows:
        g = (r["scenario"], r["stop_line"], r["platform"], r["order"])
        if g not in table:
            table[g] = {}
            groups.append(g)
        table[g][r.get("decision", "")] = table[g].get(r.get("decision", ""), 0) + 1
    groups.sort()
    return groups, table


def write_report(out_dir, title, measures, rscales, rows, collisions, skipped, info):
    """Writes the CSVs and report.html into out_dir; returns the page's path."""
    bf_rows = []
    for m in measures:
        r = {k: m.get(k) for k in ("measure", "n", "dropped", "lab_mean", "lab_sd", "road_mean", "road_sd", "t")}
        for rs in rscales:
            key = f"{rs:.6g}"
            r[f"bf10_r{key}"] = m["bf10"].get(key)
            r[f"category_r{key}"] = m["category"].get(key, "too few pairs")
        bf_rows.append(r)
    bf_cols = ["measure", "n", "dropped", "lab_mean", "lab_sd", "road_mean", "road_sd", "t"] + \
        [c for rs in rscales for c in (f"bf10_r{rs:.6g}", f"category_r{rs:.6g}")]
    write_csv(out_dir / "bayes_factors.csv", bf_rows, bf_cols)
    dist = [{"measure": m["measure"], "platform": pl, **{str(v): m[pl].count(v) for v in range(1, 6)}}
            for m in measures for pl in PLATFORMS]
    write_csv(out_dir / "rating_distributions.csv", dist, ["measure", "platform", "1", "2", "3", "4", "5"])
    diffs = [{"measure": m["measure"], **{str(v): int(np.sum(np.array(m["road"]) - np.array(m["lab"]) == v))
                                          for v in range(-4, 5)}} for m in measures]
    write_csv(out_dir / "comparison_histograms.csv", diffs, ["measure"] + [str(v) for v in range(-4, 5)])
    write_csv(out_dir / "encounters.csv", rows, ENCOUNTER_COLUMNS)
    write_csv(out_dir / "collisions.csv", collisions,
              ["participant", "platform", "order", "recording", "scenario", "stop_line", "agent", "t_s"])
    groups, table = decisions_table(rows)
    dec_cols = ["scenario", "stop_line", "platform", "order"] + list(STATES) + ["no_press", "no_stop"]
    dec_rows = [dict(zip(dec_cols[:4], g), **table[g]) for g in groups]
    write_csv(out_dir / "decisions.csv", dec_rows, dec_cols)
    write_csv(out_dir / "skipped_recordings.csv", skipped, ["participant", "platform", "recording", "reason"])

    parts = [f"<h1>{html.escape(title)}</h1>",
             f"<p>{info['participants']} participants; {info['recordings']} recordings read, "
             f"{len(skipped)} skipped; {len(rows)} encounters; {len(collisions)} virtual collisions. "
             f"Questionnaire: {html.escape(str(info['questionnaire']))}.</p>"]
    parts.append("<h2>Questionnaires: road vs lab</h2><p>JZS Bayes factor BF10 of the paired difference "
                 "(road - lab), Cauchy prior on the effect size with scale r (R BayesFactor ttestBF, paired); "
                 "categories after Jeffreys. Participants with a missing answer are dropped from that measure "
                 "(column <i>dropped</i>).</p>")
    parts.append(_table(bf_rows, bf_cols, "num"))
    if measures:
        parts.append("<h3>Rating distributions by platform</h3>")
        parts.append(f'<img alt="rating distributions" src="{rating_distributions(measures)}">')
        parts.append("<h3>Direct comparison: road - lab, per participant</h3>")
        parts.append(f'<img alt="direct comparison" src="{comparison_histograms(measures)}">')
    parts.append("<h2>Decisions at the crosswalks</h2><p>The pedestrian's state when Proceed was pressed, "
                 "per scenario encounter, platform and order (encounters.csv has one row per encounter).</p>")
    if groups:
        parts.append(f'<img alt="decisions" src="{decisions_figure(table, groups)}">')
    parts.append(_table(dec_rows, dec_cols, "num"))
    coop = {}
    for r in rows:
        if r.get("cooperative") in ("yes", "no"):
            c = coop.setdefault(r["platform"], [0, 0])
            c[0] += r["cooperative"] == "yes"
            c[1] += 1
    parts.append("<p>Waited for a crossing pedestrian: " + "; ".join(
        f"{pl} {c[0]} of {c[1]}" for pl, c in sorted(coop.items())) + ".</p>")
    parts.append(f"<h2>Virtual collisions ({len(collisions)})</h2>")
    parts.append(_table(collisions, ["participant", "platform", "order", "scenario", "stop_line", "agent", "t_s"]))
    near = [r for r in rows if r.get("near_miss") == "yes"]
    parts.append(f"<p>Near misses (footprint within 1.0 m of the pedestrian, no contact): {len(near)}.</p>")
    parts.append("<h2>Arrival timing</h2><p>Pedestrian at its mark minus car at rest at the stop line.</p>")
    if any(r.get("arrival_offset_s") is not None for r in rows):
        parts.append(f'<img alt="timing offsets" src="{offsets_figure(rows)}">')
    if skipped:
        parts.append("<h2>Skipped recordings</h2>")
        parts.append(_table(skipped, ["participant", "platform", "recording", "reason"]))
    style = ("body{font-family:sans-serif;margin:2em;max-width:1200px}table{border-collapse:collapse;"
             "margin:1em 0;font-size:13px}td,th{border:1px solid #bbb;padding:3px 7px}th{background:#eef}"
             "img{max-width:100%}")
    page = out_dir / "report.html"
    page.write_text(f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
                    f"<style>{style}</style></head><body>{''.join(parts)}</body></html>\n")
    return page, bf_rows, dec_rows
