"""``make mutate``: mutation testing of the core and the frame cache with mutmut.

mutmut 3 (pinned in ``requirements/mutate.txt``, installed into ``.venv`` by the make
target, not a runtime dependency) copies ``core/``, ``tests/`` and ``bench/`` into
``mutants/`` (git-ignored), makes every small change it knows to the functions of the
files listed in ``pyproject.toml`` ``[tool.mutmut] only_mutate`` (an operator, a number,
a comparison, a keyword argument ...), and for each mutant runs the tests of
``tests/core``, ``tests/cache`` and ``tests/pipeline`` that reach the mutated function
(they import ``core`` as a top-level package, from ``mutants/``), fastest first, with
the hypothesis profile ``mutation`` (40 % of the examples, no shrinking). A mutant no
test notices *survives*. Then this script prints, per file, how many mutants survived,
and lists every survivor with its change and, where ``docs/mutation-survivors.md``
explains it, why it is harmless; unexplained survivors are listed first.

Usage::

    make mutate                                  # every mutant: many hours on 2 cores
    make mutate ARGS="--sample 60"               # 60 drawn mutants per file (~1 h)
    .venv/bin/python scripts/mutate.py --files core/soft.py   # one file's mutants
    .venv/bin/python scripts/mutate.py --report  # the last run's numbers, no new run
    .venv/bin/python scripts/mutate.py --report --sample 60   # that sample's numbers

Runs with ``nice -n 10`` and one worker (``--jobs``). ``--sample N`` tests ``N``
mutants per file drawn with a fixed seed (``--seed``), the same ones on every run of
the same code: the survivor rate of the sample estimates the file's. mutmut keeps
results in ``mutants/``; ``--fresh`` starts over.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MUTANTS = ROOT / "mutants"
EXPLAINED = ROOT / "docs" / "mutation-survivors.md"
GOAL = 0.10
#: How mutmut's exit codes count: a timeout or a crash is a detected mutant.
DETECTED = {"killed", "timeout", "segfault", "caught by type check"}


def _mutmut():
    exe = Path(sys.executable).with_name("mutmut")
    if not exe.exists():
        sys.exit("scripts/mutate.py: mutmut is not installed: run `make mutate` (it installs "
                 "requirements/mutate.txt into .venv)")
    return str(exe)


def configured_files() -> list[str]:
    import tomllib

    with open(ROOT / "pyproject.toml", "rb") as fh:
        return list(tomllib.load(fh)["tool"]["mutmut"]["only_mutate"])


def module_of(path: str) -> str:
    return path[:-3].replace("/", ".")


def _mutmut_run(names, jobs, log_mode="w"):
    cmd = ["nice", "-n", "10", _mutmut(), "run", "--max-children", str(jobs), *names]
    shown = names if len(names) <= 6 else names[:3] + [f"... ({len(names)} mutants)"]
    print("mutate:", " ".join(cmd[:7] + shown), flush=True)
    env = dict(os.environ, HYPOTHESIS_PROFILE="mutation")
    with open(ROOT / "mutants.log", log_mode) as log:  # mutmut draws a progress line
        rc = subprocess.call(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, env=env)
    if rc != 0:
        tail = (ROOT / "mutants.log").read_text(errors="replace")[-3000:]
        sys.exit(f"mutate: mutmut failed (exit {rc}):\n{tail}")


def all_mutants(files) -> dict[str, list[str]]:
    """{file: every mutant name mutmut generated for it} (from mutants/*.meta)."""
    out = {}
    for f in files:
        meta = MUTANTS / (f + ".meta")
        out[f] = sorted(json.loads(meta.read_text())["exit_code_by_key"]) if meta.exists() else []
    return out


def _stale(files) -> bool:
    """Was a file changed since mutmut last generated its mutants? (Their names are
    then those of the old code: a sample drawn from them would test the wrong mutants.)"""
    for f in files:
        meta = MUTANTS / (f + ".meta")
        if not meta.exists() or (ROOT / f).stat().st_mtime > meta.stat().st_mtime:
            return True
    return False


def drawn(files, sample, seed) -> list[str]:
    """The ``sample`` mutants per file that ``--sample``/``--seed`` stand for."""
    picked = []
    for f, names in all_mutants(files).items():
        if not names:
            sys.exit(f"mutate: mutmut made no mutants for {f}")
        picked += random.Random(f"{seed}:{f}").sample(names, min(sample, len(names)))
    return picked


def run(files, jobs, fresh, sample, seed):
    if fresh:
        shutil.rmtree(MUTANTS, ignore_errors=True)
    stats = MUTANTS / "mutmut-stats.json"
    if stats.exists():
        # mutmut traces which tests reach which function once, and later only new
        # tests: a test edited since would keep its old reach. Re-trace them all.
        newest = max(p.stat().st_mtime for p in (ROOT / "tests").rglob("*.py"))
        if newest > stats.stat().st_mtime:
            stats.unlink()
    if not sample:
        _mutmut_run([module_of(f) + ".*" for f in files], jobs)
        return
    if not all(all_mutants(files).values()) or _stale(files):
        # mutmut generates the mutants (and records which tests reach which function)
        # when a run starts: prepare with one mutant of the cheapest file, the cache,
        # so that the sample is drawn from the mutants of the code as it is now
        print("mutate: generating the mutants", flush=True)
        _mutmut_run(["core.framecache.x_frame_path__mutmut_1"], jobs)
    _mutmut_run(drawn(files, sample, seed), jobs, log_mode="a")


def results(files, only=None):
    """{file: {status: [mutant names]}} from mutmut's result files (``only``: just
    these mutants, e.g. one drawn sample)."""
    from mutmut.stats import status_by_exit_code

    out = {}
    for f in files:
        meta = MUTANTS / (f + ".meta")
        per = {}
        if meta.exists():
            codes = json.loads(meta.read_text())["exit_code_by_key"]
            for name, code in codes.items():
                if only is None or name in only:
                    per.setdefault(status_by_exit_code[code], []).append(name)
        out[f] = per
    return out


def explained() -> dict[str, str]:
    """Mutant name -> reason, from the tables of docs/mutation-survivors.md."""
    if not EXPLAINED.exists():
        return {}
    why = {}
    for line in EXPLAINED.read_text().splitlines():
        m = re.match(r"\|\s*`([\w.ǁ]+__mutmut_\d+)`\s*\|(?:[^|\\]|\\.)*\|\s*(.*?)\s*\|\s*$",
                     line)
        if m:
            why[m.group(1)] = m.group(2)
    return why


def change_of(name: str) -> str:
    """The mutated line(s), as mutmut shows them (one line per side)."""
    p = subprocess.run([_mutmut(), "show", name], cwd=ROOT, capture_output=True, text=True)
    lines = [ln for ln in p.stdout.splitlines()
             if ln[:1] in "+-" and not ln.startswith(("+++", "---"))]
    return " / ".join(ln[0] + " " + ln[1:].strip() for ln in lines)[:160]


def report(files, with_changes=True, only=None) -> int:
    res = results(files, only)
    why = explained()
    head = "mutate: HEAD " + subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                                           capture_output=True, text=True).stdout.strip()
    print(head)
    print("| file | mutants | detected | survived | no tests | survived % |")
    print("|---|---|---|---|---|---|")
    over, unexplained, total = [], [], [0, 0]
    for f, per in res.items():
        n = sum(len(v) for k, v in per.items() if k not in ("not checked",))
        det = sum(len(per.get(k, [])) for k in DETECTED)
        surv = per.get("survived", []) + per.get("suspicious", [])
        none = per.get("no tests", [])
        bad = len(surv) + len(none)
        rate = bad / n if n else 0.0
        total[0] += n
        total[1] += bad
        print(f"| `{f}` | {n} | {det} | {len(surv)} | {len(none)} | {100 * rate:.1f} % |")
        if rate > GOAL:
            over.append(f)
        unexplained += [m for m in surv + none if m not in why]
        if per.get("not checked"):
            print(f"  ({len(per['not checked'])} mutants of {f} not checked yet)")
    if total[0]:
        print(f"| all | {total[0]} | | {total[1]} | | {100 * total[1] / total[0]:.1f} % |")
    if unexplained:
        print(f"\n{len(unexplained)} survivors not explained in {EXPLAINED.relative_to(ROOT)}:")
        for m in unexplained:
            print(f"  {m}: {change_of(m) if with_changes else ''}")
    if over:
        print(f"\nabove the {100 * GOAL:.0f} % goal: {', '.join(over)}")
    return 0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--files", nargs="*", help="only these files (default: pyproject's list)")
    ap.add_argument("--jobs", type=int, default=1, help="parallel mutant workers (default 1)")
    ap.add_argument("--sample", type=int, default=0,
                    help="test N drawn mutants per file (default 0: all)")
    ap.add_argument("--seed", type=int, default=16, help="seed of --sample (default 16)")
    ap.add_argument("--report", action="store_true", help="only report the last run")
    ap.add_argument("--fresh", action="store_true", help="forget earlier results first")
    ap.add_argument("--no-changes", action="store_true", help="list survivors without diffs")
    args = ap.parse_args(argv)
    os.chdir(ROOT)
    files = args.files or configured_files()
    unknown = [f for f in files if f not in configured_files()]
    if unknown:
        sys.exit(f"mutate: not in [tool.mutmut] only_mutate: {unknown}")
    if not args.report:
        run(files, args.jobs, args.fresh, args.sample, args.seed)
    # a sample's figures are the sample's alone (other mutants may have results too)
    only = set(drawn(files, args.sample, args.seed)) if args.sample else None
    return report(files, with_changes=not args.no_changes, only=only)


if __name__ == "__main__":
    sys.exit(main())
