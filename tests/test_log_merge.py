"""tools/log-merge: time order, ties, --drop, and damaged inputs."""
import lcm

from conftest import BIN, read_log, run


def write_log(path, events):
    log = lcm.EventLog(str(path), "w", overwrite=True)
    for ch, t, data in events:
        log.write_event(t, ch, data)
    log.close()


def test_merge_orders_by_time_and_keeps_input_order_on_ties(tmp_path):
    a, b, out = tmp_path / "a.lcm", tmp_path / "b.lcm", tmp_path / "out.lcm"
    write_log(a, [("A", 10, b"a1"), ("A", 30, b"a2"), ("A", 30, b"a3"), ("X", 50, b"a4")])
    write_log(b, [("B", 5, b"b1"), ("B", 30, b"b2"), ("B", 60, b"b3")])
    run([BIN / "log-merge", "--quiet", "--out", out, a, b])
    got = [(ch, t, d) for ch, t, d in read_log(out)]
    assert got == [("B", 5, b"b1"), ("A", 10, b"a1"), ("A", 30, b"a2"), ("A", 30, b"a3"),
                   ("B", 30, b"b2"), ("X", 50, b"a4"), ("B", 60, b"b3")]
    out2 = tmp_path / "out2.lcm"
    run([BIN / "log-merge", "--quiet", "--drop", "X", "--drop", "B", "--out", out2, a, b])
    assert [d for _, _, d in read_log(out2)] == [b"a1", b"a2", b"a3"]


def test_damaged_input_is_named_and_earlier_events_are_kept(tmp_path):
    a, out = tmp_path / "a.lcm", tmp_path / "out.lcm"
    write_log(a, [("A", t, b"x" * 100) for t in range(1, 11)])
    raw = a.read_bytes()
    # The last event cut short (a recording cut by a power loss): read up to the cut, with a
    # warning naming the byte offset, and a clean exit.
    a.write_bytes(raw[:-50])
    p = run([BIN / "log-merge", "--quiet", "--out", out, a], check=False)
    assert p.returncode == 0, p.stderr
    assert f"{a}: byte {len(raw) - 129}: warning: the last event is torn" in p.stderr
    assert len(list(read_log(out))) == 9
    # Damage inside the file: an error naming the byte offset, earlier events kept.
    a.write_bytes(raw[:5 * 129] + b"JUNK" + raw[5 * 129 + 4:])
    p = run([BIN / "log-merge", "--quiet", "--out", out, a], check=False)
    assert p.returncode == 1
    assert f"{a}: byte {5 * 129}: bad sync word" in p.stderr
    assert len(list(read_log(out))) == 5


def test_bad_options(tmp_path):
    a = tmp_path / "a.lcm"
    write_log(a, [("A", 1, b"x")])
    assert run([BIN / "log-merge", "--out", a, a], check=False).returncode == 2
    assert run([BIN / "log-merge", a], check=False).returncode == 2
    p = run([BIN / "log-merge", "--quiet", "--out", tmp_path / "o.lcm", tmp_path / "missing.lcm"], check=False)
    assert p.returncode == 1 and "missing.lcm" in p.stderr
    assert "usage" in run([BIN / "log-merge", "--help"]).stdout
