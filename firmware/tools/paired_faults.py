#!/usr/bin/env python3
"""Paired comparison of two `visco faults --seeds N --json F` reports (issue 14, round 9).

    python3 firmware/tools/paired_faults.py OLD.json NEW.json [--null NULL.json]...
    python3 firmware/tools/paired_faults.py --selftest

The runs of a class come in seed order (1..N), so the k-th run of a class in OLD and NEW is
the same seed. Per class and per quantity (max_force_n in nN, recovery_s in ms): mean old,
mean new, the paired mean difference d = new - old, its standard error sd(d)/sqrt(n), and the
verdict: "ok" when mean(d) <= 0 or mean(d) <= 2 SE, else "WORSE". A run that is unbounded or
at/over the force limit, or a recovery that is None in NEW but not in OLD, is "UNSAFE"/"WORSE".
A class whose runs carry `retract_s` (dive-force-limit, issue 14 round 11: the time from the
contact to the retract on the force limit) is judged on it in place of the recovery.
A difference below the reports' resolution (1e-6 nN or ms, with no spread) counts as none.

With --null (issue 14, round 16): NULL is a run of OLD changed imperceptibly (e.g. a DAC scale
by one ulp), which moves every row by the chaos of the runs alone. A class that is WORSE
against OLD is "ok vs nulls" when it is ok against every NULL: NEW moved it no further than
an imperceptible change of OLD does. UNSAFE stays UNSAFE.
Exit status 1 when any verdict is neither "ok" nor "ok vs nulls".
"""
import json
import math
import sys
from collections import OrderedDict


def by_class(report):
    out = OrderedDict()
    for r in report["runs"]:
        out.setdefault(r["class"], []).append(r)
    return out


# The reports' resolution in nN and ms: a mean difference below it, with no spread, is
# rounding (e.g. a DAC scale changed by 10^-7 moves every force by ~1e-10 nN).
RESOLUTION = 1e-6


def paired(old, new):
    d = [b - a for a, b in zip(old, new)]
    n = len(d)
    m = sum(d) / n
    sd = math.sqrt(sum((x - m) ** 2 for x in d) / (n - 1)) if n > 1 else 0.0
    se = sd / math.sqrt(n)
    return sum(old) / n, sum(new) / n, m, se, ("ok" if m <= 2 * se + RESOLUTION else "WORSE")


def when(r):
    """The run's time quantity (s): its retract on the force limit when it has one, else its
    recovery."""
    return r["recovery_s"] if r.get("retract_s") is None else r["retract_s"]


def compare(old_rep, new_rep):
    rows, ok = [], True
    old_c, new_c = by_class(old_rep), by_class(new_rep)
    for cls, olds in old_c.items():
        news = new_c[cls]
        assert len(olds) == len(news), cls
        unsafe = [i + 1 for i, r in enumerate(news)
                  if not r["bounded"] or not r["max_force_n"] < r["force_limit_n"]]
        f = paired([r["max_force_n"] * 1e9 for r in olds], [r["max_force_n"] * 1e9 for r in news])
        lost = [i + 1 for i, (a, b) in enumerate(zip(olds, news))
                if when(a) is not None and when(b) is None]
        pairs = [(when(a) * 1e3, when(b) * 1e3) for a, b in zip(olds, news)
                 if when(a) is not None and when(b) is not None]
        r = paired([p[0] for p in pairs], [p[1] for p in pairs]) if pairs else None
        if r and lost:
            r = r[:4] + ("WORSE",)
        verdict = "UNSAFE" if unsafe else ("ok" if f[4] == "ok" and (r is None or r[4] == "ok") else "WORSE")
        ok &= verdict == "ok"
        rows.append((cls, len(olds), unsafe, f, r, len(pairs), lost, verdict))
    return rows, ok


def against_nulls(rows, new_rep, nulls):
    """Rows WORSE against OLD re-judged against each null run (see the module's doc)."""
    if not nulls:
        return rows, all(r[7] == "ok" for r in rows)
    judged = [dict((r[0], r[7]) for r in compare(n, new_rep)[0]) for n in nulls]
    out, ok = [], True
    for r in rows:
        v = r[7]
        if v == "WORSE" and all(j[r[0]] == "ok" for j in judged):
            v = "ok vs nulls"
        ok &= v in ("ok", "ok vs nulls")
        out.append(r[:7] + (v,))
    return out, ok


def show(rows):
    print("| class | n | force old / new (nN) | d ± SE (nN) | recovery (retract) old / new (ms) | d ± SE (ms) | verdict |")
    print("|---|---|---|---|---|---|---|")
    for cls, n, unsafe, f, r, nr, lost, verdict in rows:
        rec = ("%.3f / %.3f | %+.3f ± %.3f%s" % (r[0], r[1], r[2], r[3],
               "" if nr == n else " (%d pairs)" % nr)) if r else "— | —"
        extra = (" unsafe seeds %s" % unsafe if unsafe else "") + (" lost recovery %s" % lost if lost else "")
        print("| %s | %d | %.3f / %.3f | %+.3f ± %.3f | %s | %s%s |"
              % (cls, n, f[0], f[1], f[2], f[3], rec, verdict, extra))


def selftest():
    def rep(cls, forces, recs, bounded=True):
        return [{"class": cls, "bounded": bounded, "max_force_n": x * 1e-9,
                 "force_limit_n": 150e-9, "recovery_s": None if y is None else y * 1e-3}
                for x, y in zip(forces, recs)]
    old = {"runs": rep("a", [1, 2, 3, 4], [1, 1, 1, 1]) + rep("b", [1, 2, 3, 4], [1, 1, 1, 1])}
    # a: forces +0.1 each (sd 0): worse; b: d = [+1, -1, +1, -1] -> mean 0: ok.
    new = {"runs": rep("a", [1.1, 2.1, 3.1, 4.1], [1, 1, 1, 1])
           + rep("b", [2, 1, 4, 3], [1, 1, 1, 1])}
    rows, ok = compare(old, new)
    assert not ok and rows[0][7] == "WORSE" and rows[1][7] == "ok", rows
    assert abs(rows[0][3][2] - 0.1) < 1e-9 and abs(rows[1][3][2]) < 1e-12
    # d = [1, 0, 0, 0]: mean 0.25, SE 0.25 -> within 2 SE: ok.
    rows, ok = compare({"runs": rep("c", [0, 0, 0, 0], [1, 1, 1, 1])},
                       {"runs": rep("c", [1, 0, 0, 0], [1, 1, 1, 1])})
    assert ok and abs(rows[0][3][3] - 0.25) < 1e-12, rows
    # A lost recovery and an over-limit run.
    rows, ok = compare({"runs": rep("d", [1, 1], [1, 1])}, {"runs": rep("d", [1, 1], [1, None])})
    assert not ok and rows[0][7] == "WORSE"
    rows, ok = compare({"runs": rep("e", [1, 1], [1, 1])}, {"runs": rep("e", [1, 151], [1, 1])})
    assert not ok and rows[0][7] == "UNSAFE"
    # Runs with a retract are judged on it (the recovery None in both): 1 ms later is worse.
    def ret(rs, ts):
        for r, t in zip(rs, ts):
            r["recovery_s"], r["retract_s"] = None, t * 1e-3
        return rs
    rows, ok = compare({"runs": ret(rep("f", [1, 1], [1, 1]), [6, 6])},
                       {"runs": ret(rep("f", [1, 1], [1, 1]), [7, 7])})
    assert not ok and rows[0][7] == "WORSE" and abs(rows[0][4][2] - 1.0) < 1e-9, rows
    # A difference below the resolution with no spread is none.
    rows, ok = compare({"runs": rep("g", [1, 2], [1, 1])},
                       {"runs": rep("g", [1 + 1e-10, 2 + 1e-10], [1, 1])})
    assert ok, rows
    # Against nulls: WORSE against OLD, but a null moved it as far: ok vs nulls; a null that
    # did not move it keeps the verdict.
    old = {"runs": rep("h", [1, 2, 3, 4], [1, 1, 1, 1])}
    new = {"runs": rep("h", [1.1, 2.1, 3.1, 4.1], [1, 1, 1, 1])}
    moved = {"runs": rep("h", [1.1, 2.1, 3.1, 4.1], [1, 1, 1, 1])}
    rows, ok = against_nulls(compare(old, new)[0], new, [moved])
    assert ok and rows[0][7] == "ok vs nulls", rows
    rows, ok = against_nulls(compare(old, new)[0], new, [moved, old])
    assert not ok and rows[0][7] == "WORSE", rows
    print("selftest ok")


if __name__ == "__main__":
    if sys.argv[1:] == ["--selftest"]:
        selftest()
        sys.exit(0)
    args = sys.argv[1:]
    nulls = []
    while "--null" in args:
        i = args.index("--null")
        if i + 1 >= len(args):
            sys.exit(__doc__)
        nulls.append(json.load(open(args[i + 1])))
        del args[i:i + 2]
    if len(args) != 2:
        sys.exit(__doc__)
    new_rep = json.load(open(args[1]))
    rows, ok = against_nulls(compare(json.load(open(args[0])), new_rep)[0], new_rep, nulls)
    show(rows)
    sys.exit(0 if ok else 1)
