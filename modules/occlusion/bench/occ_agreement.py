"""Agreement of OCCLUSION with simdrive's OCCLUSION_TRUTH, per sample.

Messages are paired by utime (the sweep's end) and agents by id; a sample counts when
it lies within RANGE_M of the truth's eye and its agent is in render range (the module
evaluates only those). Returns the confusion matrix (truth visible/hidden x module
visible/hidden/unknown), the agreement, the "visible when truly hidden" rate, and how
many truth state changes the module followed within one sweep.

    python occ_agreement.py TRUTH.lcm OCCLUSION.lcm   (prints the figures as JSON)
"""
import json
import math
import sys

RANGE_M = 45.0
STATES = ("visible", "hidden", "unknown")


def read(path, channel, extra=None):
    import lcm
    from portobello import occlusion_t, agents_t
    out, in_range = {}, {}
    for ev in lcm.EventLog(path, "r"):
        if ev.channel == channel:
            m = occlusion_t.decode(ev.data)
            out[m.utime] = m
        elif extra is not None and ev.channel == "AGENTS":
            a = agents_t.decode(ev.data)
            in_range[a.utime] = {g.id: g.in_render_range for g in a.agents}
    return out, in_range


def agreement(truth_path, out_path, out_channel="OCCLUSION", utimes=None):
    truth, agents = read(truth_path, "OCCLUSION_TRUTH", extra=True)
    mod, _ = read(out_path, out_channel)
    agent_times = sorted(agents)
    conf = [[0, 0, 0], [0, 0, 0]]
    series = {}         # (agent, sample) -> [(sweep index, truth, module)]
    paired = 0
    import bisect
    for i, t in enumerate(sorted(truth)):
        if t not in mod or (utimes is not None and t not in utimes):
            continue
        paired += 1
        tm, mm = truth[t], mod[t]
        k = bisect.bisect_right(agent_times, t) - 1
        rng = agents[agent_times[k]] if k >= 0 else {}
        by_id = {a.agent_id: a for a in mm.agents}
        for a in tm.agents:
            b = by_id.get(a.agent_id)
            if not rng.get(a.agent_id, False):
                continue
            for s in range(a.nsamples):
                d = math.dist((a.sample_x[s], a.sample_y[s], a.sample_z[s]), tm.viewer)
                if d > RANGE_M:
                    continue
                ms = b.state[s] if b is not None and s < b.nsamples else 2
                conf[a.state[s]][ms] += 1
                series.setdefault((a.agent_id, s), []).append((i, a.state[s], ms))
    # state changes of the truth (visible <-> hidden between consecutive sweeps) and
    # whether the module shows the new state at that sweep or the next
    changes = followed = 0
    for seq in series.values():
        for j in range(1, len(seq)):
            (i0, t0, _), (i1, t1, m1) = seq[j - 1], seq[j]
            if i1 != i0 + 1 or t0 == t1:
                continue
            changes += 1
            nxt = seq[j + 1] if j + 1 < len(seq) and seq[j + 1][0] == i1 + 1 else None
            if m1 == t1 or (nxt is not None and nxt[2] == t1):
                followed += 1
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
        "state_changes": changes,
        "changes_within_one_sweep": followed / changes if changes else float("nan"),
    }


if __name__ == "__main__":
    print(json.dumps(agreement(sys.argv[1], sys.argv[2]), indent=1))
