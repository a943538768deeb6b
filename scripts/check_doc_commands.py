"""Check that every command in the README's and docs' code blocks still works.

    .venv/bin/python scripts/check_doc_commands.py          # every command's arguments (seconds)
    .venv/bin/python scripts/check_doc_commands.py --run    # and the README's, run at smoke size

Without ``--run`` each command's arguments are checked as its program reads them: ``train.py``'s
overrides compose into a valid config (a multirun's first job), ``evaluate.py`` and ``record``'s
keys exist, ``analyse.py`` and ``sweep``'s arguments parse, and every ``--option`` given to a
benchmark is one its ``--help`` lists. With ``--run`` the README's commands also run, at smoke size
(a few iterations of a few worlds), against run directories they make themselves. A command that
needs something no checkout has (a finished sweep's ``best`` experiment) is reported as skipped.
"""

from __future__ import annotations

import argparse
import functools
import re
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROGRAM = re.compile(
    r"roto_trl/(train|evaluate|analyse)\.py|-m roto_trl\.(record|sweep|random_rollout)|benchmarks/\w+\.py"
)
SMOKE = [
    "env.num_envs=4",
    "agent.rollout_len=16",
    "agent.minibatches=2",
    "agent.epochs=1",
    "total_frames=128",
    "eval.num_envs=2",
    "eval.every_frames=64",
    "+env.overrides.episode_steps=20",
    "checkpoint.interval_minutes=0",
    "logger=csv",
    "progress=false",
    "torch_threads=1",
]


def commands(path: Path) -> list[str]:
    """The commands of a Markdown file's shell code blocks (```bash, ```sh or bare ```) that start
    one of our programs."""
    found, language, block = [], None, []
    for line in path.read_text().splitlines():
        if line.lstrip().startswith("```"):
            if language is None:
                language, block = line.strip().removeprefix("```").strip(), []
                continue
            if language in ("", "bash", "sh"):
                for command in "\n".join(block).replace("\\\n", " ").splitlines():
                    if PROGRAM.search(command) and not command.lstrip().startswith("#"):  # a comment: shown
                        command = re.sub(r"\s#\s.*$", "", command)  # a trailing comment
                        found.append(without_optional(command).split("&&")[-1].strip())
            language = None
            continue
        if language is not None:
            block.append(line)
    return found


def without_optional(line: str) -> str:
    """``line`` without its optional parts, `` [--compile]`` or `` [--set 'a=[1,2]']`` (a bracket
    after a space, to its matching bracket)."""
    out, depth = [], 0
    for i, char in enumerate(line):
        if char == "[" and (depth or (i and line[i - 1] == " ")):
            depth += 1
            continue
        if char == "]" and depth:
            depth -= 1
            continue
        if not depth:
            out.append(char)
    return "".join(out)


def arguments(command: str) -> tuple[str, list[str]]:
    """``(program, arguments)`` of a command line."""
    words = shlex.split(command)
    words = [w for w in words if "=" not in w or not w.split("=")[0].isupper()]  # VAR=value prefixes
    if len(words) > 2 and words[1] == "-m":  # python -m <module> (train.py's own -m is a multirun)
        return words[2], words[3:]
    script = next(w for w in words if w.endswith(".py"))
    return script, words[words.index(script) + 1 :]


def first_job(args: list[str]) -> list[str]:
    """A multirun's first job: ``-m`` and Hydra's own keys left out, comma lists to their first value."""
    out = []
    for arg in args:
        if arg == "-m" or arg.startswith(("hydra.", "hydra/")):
            continue
        key, _, value = arg.partition("=")
        if value.startswith("glob("):
            value = "bounce_ppo"
        elif "," in value and not value.startswith(("[", "{")):
            value = value.split(",")[0]
        out.append(f"{key}={value}" if _ else arg)
    return out


def check(program: str, args: list[str]) -> str | None:
    """Why the command's arguments are wrong, or None; ``"skip: ..."`` for what needs a run."""
    from roto_trl.config import checked_config, compose_train
    from roto_trl.trainers.run_dir import RESUMABLE, override_keys

    if program.endswith("train.py"):
        job = [a for a in first_job(args) if a != "device=cuda"]  # checked as on a machine without one
        if any(a.startswith("resume=") for a in job):
            bad = [k for k in override_keys(job) if k not in RESUMABLE]
            return f"resume= takes only {RESUMABLE}, not {bad}" if bad else None
        if any(re.search(r"exp=\w+_best\b", a) for a in job):
            return "skip: a sweep's best experiment (python -m roto_trl.sweep best writes it)"
        try:
            checked_config(compose_train([a for a in job if not a.startswith("hparams_search")]))
        except Exception as err:
            return f"{type(err).__name__}: {str(err).splitlines()[0]}"
        return None
    if program.endswith("evaluate.py") or program == "roto_trl.record":
        from roto_trl.evaluate import DEFAULTS as evaluate_keys
        from roto_trl.record import DEFAULTS as record_keys

        keys = evaluate_keys if program.endswith("evaluate.py") else record_keys
        unknown = [a.split("=")[0] for a in args if a.split("=")[0].split(".")[0] not in keys]
        return f"unknown keys {unknown}" if unknown else None
    if program.endswith("analyse.py") or program == "roto_trl.sweep":
        from roto_trl.analyse import parse_args as analyse_args
        from roto_trl.sweep import parse_args as sweep_args

        try:
            (analyse_args if program.endswith("analyse.py") else sweep_args)(args)
        except SystemExit as stop:
            return f"its arguments do not parse (exit {stop.code})"
        return None
    if program == "roto_trl.random_rollout":
        return None
    if not program.startswith("benchmarks/"):
        return f"not a program this script knows: {program}"
    unknown = [a for a in args if a.startswith("--") and a.split("=")[0] not in help_text(program)]
    return f"options its --help does not list: {unknown}" if unknown else None


@functools.cache
def help_text(program: str) -> str:
    """What ``python <program> --help`` prints (once per benchmark)."""
    return subprocess.run(
        [sys.executable, str(ROOT / program), "--help"], capture_output=True, text=True
    ).stdout


def run_readme(commands: list[str]) -> list[str]:
    """Run the README's commands at smoke size; the failures."""
    failures = []
    with tempfile.TemporaryDirectory() as tmp:
        runs = Path(tmp) / "runs"
        made = {}
        for command in commands:
            program, args = arguments(command)
            if program.endswith("train.py") and not any(a.startswith("resume=") for a in args):
                job = [
                    a for a in first_job(args) if a != "device=cuda" and not a.startswith("hparams_search")
                ]
                exp = next((a.split("=")[1] for a in job if a.startswith("+exp=")), "find_ppo")
                run = runs / exp / f"{len(made)}-s0"
                made.setdefault(exp, run)
                argv = [*job, *SMOKE, f"run_dir={run}"]
            else:
                argv = list(args)
                for i, arg in enumerate(argv):  # placeholders -> a run the commands above made
                    exp = next((e for e in made if f"/{e}/" in arg or f"runs/{e}" in arg), None)
                    if "<" in arg and exp:
                        argv[i] = re.sub(r"runs/\w+/<[^>]+>", str(made[exp]), arg)
                if program.endswith("train.py"):  # resume=: the first run made, a few frames more
                    argv = [f"resume={next(iter(made.values()))}", "total_frames=256"]
                if program == "roto_trl.sweep":
                    continue  # needs a finished sweep: its arguments are checked above
                if program.endswith("analyse.py") and argv[0] in ("mi",):
                    argv += ["--worlds", "2", "--samples", "20", "--pca", "2"]
            cmd = [
                sys.executable,
                *(["-m", program] if not program.endswith(".py") else [str(ROOT / program)]),
                *argv,
            ]
            done = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp)
            status = (
                "ok" if done.returncode == 0 else f"FAILED ({done.returncode}): {done.stderr.strip()[-300:]}"
            )
            print(f"  run {command[:90]}: {status}", flush=True)
            if done.returncode != 0:
                failures.append(command)
    return failures


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--run", action="store_true", help="also run the README's commands at smoke size")
    args = parser.parse_args(argv)
    files = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    failures = 0
    for path in files:
        for command in commands(path):
            problem = check(*arguments(command))
            if problem and not problem.startswith("skip"):
                failures += 1
                print(f"{path.relative_to(ROOT)}: {command}\n  {problem}")
            elif problem:
                print(f"{path.relative_to(ROOT)}: {command}\n  {problem}")
    if args.run:
        failures += len(run_readme(commands(ROOT / "README.md")))
    print(f"{failures} command(s) failed" if failures else "every command checked")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
