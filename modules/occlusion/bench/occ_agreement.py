"""Agreement of OCCLUSION with simdrive's OCCLUSION_TRUTH, per sample.

Messages are paired by utime (the sweep's end) and agents by id; a sample counts when
it lies within RANGE_M of the truth's eye and its agent is in render range (the module
evaluates only those; the newest AGENTS at or before the sweep says). Returns the
confusion matrix (truth visible/hidden x module visible/hidden/unknown), the agreement,
the "visible when truly hidden" rate, and how many truth state changes the module
followed within one sweep (raw, and of those a one-sweep answer can follow; the rest by
cause: see changes_followed).

Logs are read once, streaming, and only the states are kept (a 10-minute drive's truth
decoded whole would not fit in memory).

    python occ_agreement.py TRUTH.lcm OCCLUSION.lcm   (prints the figures as JSON)
"""
import json
import math
import sys

RANGE_M = 45.0
STATES = ("visible", "hidden", "unknown")


def read_truth(path):
    """[(utime, {agent_id: ((sample index, truth state), ...)})] in log order: the samples
    that count (agent in render range, sample within RANGE_M of the eye)."""
    import lcm
    from portobello import occlusion_t, agents_t
    out, in_range = [], {}
    for ev in lcm.EventLog(path, "r"):
        if ev.channel == "AGENTS":
            a = agents_t.decode(ev.data)
            in_range = {g.id: g.in_render_range for g in a.agents}
        elif ev.channel == "OCCLUSION_TRUTH":
            m = occlusion_t.decode(ev.data)
            ags = {}
            for a in m.agents:
                if not in_range.get(a.agent_id, False):
                    continue
                keep = tuple((s, a.state[s]) for s in range(a.nsamples)
                             if math.dist((a.sample_x[s], a.sample_y[s], a.sample_z[s]), m.viewer) <= RANGE_M)
                if keep:
                    ags[a.agent_id] = keep
            out.append((m.utime, ags))
    return out


def read_states(path, channel):
    """{utime: {agent_id: bytes of per-sample states}} of one channel."""
    import lcm
    from portobello import occlusion_t
    out = {}
    for ev in lcm.EventLog(path, "r"):
        if ev.channel == channel:
            m = occlusion_t.decode(ev.data)
            out[m.utime] = {a.agent_id: bytes(s & 0xff for s in a.state) for a in m.agents}
    return out


def read(path, channel):
    """({utime: states by agent}, None): the utimes a channel has (kept for the bench's callers)."""
    return read_states(path, channel), None


def agreement(truth, out, out_channel="OCCLUSION", utimes=None):
    """truth: a log path or read_truth's result; out: a log path or read_states's result."""
    if isinstance(truth, (str, bytes)) or hasattr(truth, "__fspath__"):
        truth = read_truth(truth)
    mod = read_states(out, out_channel) if isinstance(out, (str, bytes)) or hasattr(out, "__fspath__") else out
    conf = [[0, 0, 0], [0, 0, 0]]
    series = {}         # (agent, sample) -> [(sweep index, truth, module)]
    paired = 0
    for i, (t, ags) in enumerate(truth):
        if t not in mod or (utimes is not None and t not in utimes):
            continue
        paired += 1
        mm = mod[t]
        for aid, samples in ags.items():
            b = mm.get(aid)
            for s, ts in samples:
                ms = b[s] if b is not None and s < len(b) else 2
                conf[ts][ms] += 1
                series.setdefault((aid, s), []).append((i, ts, ms))
    ch = changes_followed(series)
    total = sum(map(sum, conf))
    hidden = sum(conf[1])
    return {
        "sweeps_paired": paired,
        "samples": total,
        "confusion": {f"truth_{STATES[r]}": {f"module_{STATES[c]}": conf[r][c] for c in range(3)} for r in range(2)},
        "agreement": (conf[0][0] + conf[1][1]) / total if total else float("nan"),
        "visible_when_hidden_of_hidden": conf[1][0] / hidden if hidden else float("nan"),
        "visible_when_hidden_of_all": conf[1][0] / total if total else float("nan"),
        "unknown_fraction": (conf[0][2] + conf[1][2]) / total if total else float("nan"),
        "state_changes": ch["changes"],
        "changes_within_one_sweep": ch["followed"] / ch["changes"] if ch["changes"] else float("nan"),
        "changes_followable": ch["followable"],
        "followable_within_one_sweep": ch["followed_followable"] / ch["followable"] if ch["followable"] else float("nan"),
        "changes_not_followed": ch["not_followed"],
    }


# Why a truth change was not followed within one sweep (see changes_followed).
CAUSES = ("truth_flicker", "sample_leaves", "module_unknown", "late_by_1", "late_by_2_or_more", "never")


def changes_followed(series):
    """Truth state changes (visible <-> hidden between consecutive sweeps) and whether the
    module shows the new state at that sweep or the next ("within one scan").

    Two kinds of change cannot be judged that way, and are counted apart (the raw figure
    keeps them): the truth's new state lasts a single sweep (at the next sweep it is back:
    a system answering one sweep later, as any does that sees the occluder move in the
    sweep that shows it, can follow it only by chance), and the sample has no next sweep
    (it leaves the 45 m range or the render range). Unfollowed changes get a cause:
    truth_flicker, sample_leaves, module_unknown (unknown at both sweeps), late_by_1 (the
    new state two sweeps after the change), late_by_2_or_more, never (the truth changed
    again first); each split by the new state (to_visible / to_hidden)."""
    changes = followed = followable = followed_followable = 0
    causes = {c: {"to_visible": 0, "to_hidden": 0} for c in CAUSES}
    for seq in series.values():
        pos = {e[0]: j for j, e in enumerate(seq)}
        for j in range(1, len(seq)):
            (i0, t0, _), (i1, t1, m1) = seq[j - 1], seq[j]
            if i1 != i0 + 1 or t0 == t1:
                continue
            changes += 1
            nxt = seq[pos[i1 + 1]] if i1 + 1 in pos else None
            ok = m1 == t1 or (nxt is not None and nxt[2] == t1)
            judged = nxt is not None and nxt[1] == t1
            followed += ok
            followable += judged
            followed_followable += ok and judged
            if ok:
                continue
            if nxt is None:
                cause = "sample_leaves"
            elif nxt[1] != t1:
                cause = "truth_flicker"
            elif m1 == 2 and nxt[2] == 2:
                cause = "module_unknown"
            else:
                cause, k = "never", j + 2
                while k < len(seq) and seq[k][0] == seq[k - 1][0] + 1 and seq[k][1] == t1:
                    if seq[k][2] == t1:
                        cause = "late_by_1" if seq[k][0] == i1 + 2 else "late_by_2_or_more"
                        break
                    k += 1
            causes[cause]["to_hidden" if t1 == 1 else "to_visible"] += 1
    return dict(changes=changes, followed=followed, followable=followable,
                followed_followable=followed_followable, not_followed=causes)


if __name__ == "__main__":
    print(json.dumps(agreement(sys.argv[1], sys.argv[2]), indent=1))
