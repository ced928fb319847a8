"""The critical mutations (issue 23): named bugs that must each be caught by the tests that name them.

Each mutation replaces one exact snippet of one source file, in a temporary copy of the tree (the
working tree is never touched), then runs its tests there; the mutation is *killed* when they fail
(pytest exit 1) and *survives* when they pass. The script exits 1 if any survives, and 2 if the
unmutated copy fails those tests or a snippet no longer occurs exactly once (the code moved on: update
the snippet here, in the same commit). CI runs it from .ci/run; it takes a few minutes.

    .venv/bin/python scripts/mutation_critical.py                 # every mutation
    .venv/bin/python scripts/mutation_critical.py lambda-hardcoded-1 cas-no-compare-dir
    .venv/bin/python scripts/mutation_critical.py --list
    .venv/bin/python scripts/mutation_critical.py --source head   # the last commit, not the working tree

The broad sweep over the learner, methods, stage loop, metrics and store is mutmut
(scripts/mutation_full.py, docs/MUTATION.md).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WIRING = "tests/test_method_wiring.py"
BRANCHES = "tests/test_method_branches.py"


@dataclass(frozen=True)
class Mutation:
    name: str
    path: str
    old: str
    new: str
    tests: tuple[str, ...]  # pytest arguments (files, node ids, -k expressions)
    why: str


MUTATIONS = (
    # ---- the method: what the learner reads ------------------------------------------------------
    Mutation(
        "accrue-becomes-sequential",
        "accrue/rl_loop.py",
        "info = learner.train_step(collector.buffer, prior, teacher, fresh_ref)",
        "info = learner.train_step(collector.buffer, None, None, fresh_ref)",
        (WIRING, "-k", "accrue_becomes_sequential or lambda_hardcoded_1"),
        "train_loop stops passing B^{<k} and the cached targets: ACCRUE trains as Sequential",
    ),
    Mutation(
        "train-step-drops-teacher",
        "stages/steps/stage_io.py",
        "return load_teacher(self.teacher_dir) if self.teacher_dir else None",
        "return None",
        ("tests/test_train_step_wiring.py",),
        "the train step stops loading the cached Eq. 3 targets (ACCRUE cannot distil at stage 2)",
    ),
    Mutation(
        "distill-dropped",
        "accrue/learner/agent.py",
        "distill = self.rules.distill and prior is not None",
        "distill = False",
        (WIRING, "-k", "accrue_becomes_sequential or lambda_hardcoded_1"),
        "the prior batch arrives but Eq. 4 is never added",
    ),
    Mutation(
        "teacher-rows-misaligned",
        "accrue/learner/replay.py",
        "return None if t is None else t[self.index.to(t.device)].to(self.state.device)",
        "return None if t is None else t[: self.index.shape[0]].to(self.state.device)",
        (WIRING, "-k", "teacher_rows_misaligned or accrue_becomes_sequential"),
        "cached targets taken from the first rows, not the sampled ones",
    ),
    Mutation(
        "teacher-at-stored-action",
        "accrue/stage_rl.py",
        'targets = compute_teacher_targets(previous, memory.column("state"), memory.column("ref"))',
        'targets = compute_teacher_targets(previous, memory.column("state"), memory.column("action"))',
        (WIRING, "-k", "teacher_targets_are_the_previous_actor"),
        "Eq. 3 evaluated at the executed action instead of the stored reference chunk ã_j",
    ),
    Mutation(
        "critic-reads-prior",
        "accrue/learner/agent.py",
        "critic_batch = Batch.cat(current, prior) if (prior is not None and self.rules.critic_on_prior) else current",
        "critic_batch = Batch.cat(current, prior) if prior is not None else current",
        (WIRING, "-k", "critic_reads_prior"),
        "ACCRUE's critic trained on B^k ∪ B^{<k} (the critic-all-replay ablation's rule)",
    ),
    Mutation(
        "critic-all-replay-ignored",
        "accrue/learner/agent.py",
        "critic_batch = Batch.cat(current, prior) if (prior is not None and self.rules.critic_on_prior) else current",
        "critic_batch = current",
        (WIRING, "-k", "critic_all_replay or er_actor_current_only"),
        "ER and the critic-all-replay ablation train the critic on B^k only",
    ),
    Mutation(
        "er-actor-current-only",
        "accrue/learner/agent.py",
        "rl = Batch.cat(cur, prior) if (prior is not None and self.rules.actor_rl_on_prior) else cur",
        "rl = cur",
        (WIRING, "-k", "er_actor_current_only"),
        "ER's Eq. 1 no longer replays B^{<k}",
    ),
    Mutation(
        "actor-not-inherited",
        "accrue/learner/continual.py",
        "learner.actor.load_state_dict(prev.actor.state_dict())",
        "learner.actor.train()",
        (WIRING, "-k", "what_a_stage_inherits"),
        "stage k starts from a fresh actor instead of θ^{k-1}",
    ),
    # ---- the hyper-parameters reach the loss -----------------------------------------------------
    Mutation(
        "lambda-hardcoded-1",
        "accrue/learner/agent.py",
        'out["actor_loss"] = losses.actor_loss_total(loss_cur, loss_prior, self.cfg.lam)',
        'out["actor_loss"] = losses.actor_loss_total(loss_cur, loss_prior, 1.0)',
        (WIRING, "-k", "lambda_hardcoded_1"),
        "λ of the config never reaches Eq. 5",
    ),
    Mutation(
        "lambda-dropped-in-eq5",
        "accrue/learner/losses.py",
        "return loss_cur if loss_prior is None else loss_cur + lam * loss_prior",
        "return loss_cur if loss_prior is None else loss_cur + loss_prior",
        (WIRING, "-k", "lambda_hardcoded_1"),
        "Eq. 5 adds L_prior unweighted",
    ),
    Mutation(
        "beta-hardcoded-0",
        "accrue/learner/agent.py",
        "loss_cur = losses.actor_loss_current(q, a.float(), ref, beta, log_prob, alpha)",
        "loss_cur = losses.actor_loss_current(q, a.float(), ref, 0.0, log_prob, alpha)",
        (WIRING, "-k", "beta_hardcoded_0"),
        "β = 0 in the Eq. 1 call whatever the config says",
    ),
    Mutation(
        "beta-term-dropped",
        "accrue/learner/losses.py",
        "loss = -q + beta * chunk_sq_dist(action, ref)",
        "loss = -q",
        (WIRING, "-k", "beta_hardcoded_0"),
        "Eq. 1 without its β‖a − ã‖² anchor",
    ),
    # ---- baselines' extra rules ------------------------------------------------------------------
    Mutation(
        "retain-interval-ignored",
        "accrue/learner/agent.py",
        'if self.rules.merge and cfg.retain_interval and self.counters["actor_updates"] % cfg.retain_interval == 0:',
        "if False:",
        (WIRING, "-k", "retain_merges"),
        "RETAIN merges only at the stage end whatever retain_interval says",
    ),
    Mutation(
        "isolated-frozen-ignored",
        "accrue/rl_loop.py",
        "acts = {t: (frozen_acts or {}).get(t, at_chosen) for t in earlier}",
        "acts = {t: at_chosen for t in earlier}",
        (WIRING, "-k", "isolated_frozen_ignored"),
        "Isolated's earlier tasks scored with the current stage's actor",
    ),
    Mutation(
        "eval-scores-base-policy",
        "accrue/rl_loop.py",
        "rates = {t: evaluator.success_rate(t, acts[t]) for t in scored}",
        "rates = {t: evaluator.success_rate(t) for t in scored}",
        ("tests/test_rl_loop.py", "-k", "grid_scores_the_deployed_actor"),
        "the evaluation grid scores π_base alone instead of the deployed actor",
    ),
    Mutation(
        "chosen-scores-base-policy",
        "accrue/rl_loop.py",
        "curves[t][state.chosen] = values.success_rate(t, acts[t])",
        "curves[t][state.chosen] = values.success_rate(t)",
        (WIRING, "-k", "isolated_frozen_ignored"),
        "earlier tasks at the chosen checkpoint are scored with π_base alone instead of their actor",
    ),
    Mutation(
        "ewc-fisher-not-squared",
        "accrue/learner/continual.py",
        "fisher[k] += grads[k].square().sum(0)",
        "fisher[k] += grads[k].abs().sum(0)",
        (BRANCHES, "-k", "ewc_fisher"),
        "the Fisher sums |score| instead of score²",
    ),
    Mutation(
        "ewc-fisher-not-averaged",
        "accrue/learner/continual.py",
        "return {k: f / max(n, 1) for k, f in fisher.items()}",
        "return {k: f for k, f in fisher.items()}",
        (BRANCHES, "-k", "ewc_fisher"),
        "the Fisher is a sum over samples, so its scale grows with ewc_samples",
    ),
    # ---- metrics, claims, the store ----------------------------------------------------------------
    Mutation(
        "claim-not-higher-flipped",
        "stages/bench/claims.py",
        "return CONTRADICTED if reference_higher else HOLDS",
        "return CONTRADICTED if reference_lower else HOLDS",
        (BRANCHES, "-k", "not_higher"),
        "a not-higher claim is contradicted by the opposite evidence",
    ),
    Mutation(
        "bootstrap-ci-wrong",
        "accrue/metrics.py",
        "    means = v[rng.integers(0, v.size, size=(resamples, v.size))].mean(1)\n    tail = (1 - confidence) / 2",
        "    means = v[rng.integers(0, v.size, size=(resamples, v.size))].mean(1)\n    tail = 1 - confidence",
        ("tests/test_metrics_continual.py", "-k", "bootstrap"),
        "the interval's tails are twice too wide a share (a 90% CI reported as 95%)",
    ),
    Mutation(
        "resolve-always-raises",
        "artifacts/resolve.py",
        "    writers.hold(store)  # whoever looks an id up",
        '    raise StoreError(f"{text}: nothing found")\n    writers.hold(store)  # whoever looks an id up',
        ("tests/test_reliability_properties.py", "-k", "resolve"),
        "resolve refuses everything (the property test alone accepts that)",
    ),
    Mutation(
        "cas-no-compare-dir",
        "artifacts/remotes/directory.py",
        "if (current[1] if current else None) != expect:",
        "if False:",
        ("tests/test_remote_cas.py", "-k", "dir"),
        "the directory remote's swap writes without comparing the expected version",
    ),
    Mutation(
        "cas-no-compare-s3",
        "artifacts/remotes/s3.py",
        'mode = "create" if expect is None else {"e_tag": expect}',
        'mode = "overwrite"',
        ("tests/test_remote_cas.py", "-k", "s3"),
        "the S3 remote's swap is a plain PUT (no If-Match / If-None-Match)",
    ),
)

PYTEST_ENV = {
    "HF_HUB_OFFLINE": "1",
    "HF_DATASETS_OFFLINE": "1",
    "TRANSFORMERS_OFFLINE": "1",
    "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"),
    "RERUN": "off",
    "OMP_NUM_THREADS": "1",
}


def copy_tree(dest: Path, source: str) -> None:
    """The tree as CI sees it: tracked and untracked-but-not-ignored files (or the last commit's)."""
    if source == "head":
        archive = subprocess.run(["git", "archive", "HEAD"], cwd=ROOT, check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
        return
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT,
        check=True,
        capture_output=True,
    ).stdout.split(b"\0")
    for raw in filter(None, listed):
        rel = raw.decode()
        src = ROOT / rel
        if src.is_file():
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)


def run_tests(tree: Path, args: tuple[str, ...], timeout: float) -> tuple[int, str]:
    env = {**os.environ, **PYTEST_ENV, "PYTHONPATH": str(tree)}
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", "-p", "no:randomly", *args]
    try:
        proc = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return 124, "timed out"
    return proc.returncode, (proc.stdout + proc.stderr)[-2000:]


def baseline_selections(chosen: list[Mutation]) -> list[tuple[str, ...]]:
    """Every mutation's selection, merged per test file: `file -k "(a) or (b)"` (a whole file stays whole)."""
    by_file: dict[str, list[str] | None] = {}
    for m in chosen:
        file, rest = m.tests[0], m.tests[1:]
        expr = rest[1] if rest[:1] == ("-k",) and len(rest) == 2 else None
        if expr is None or by_file.get(file, []) is None:
            by_file[file] = None
        else:
            by_file.setdefault(file, []).append(expr)
    return [(f,) if exprs is None else (f, "-k", " or ".join(f"({e})" for e in exprs)) for f, exprs in by_file.items()]


def check_imports_from(tree: Path) -> None:
    """The copy's packages must shadow the editable install of the real tree."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    code = "import accrue, artifacts, stages; print(accrue.__file__, artifacts.__file__, stages.__file__)"
    out = subprocess.run([sys.executable, "-c", code], cwd=tree, env=env, capture_output=True, text=True, check=True)
    if any(not Path(p).resolve().is_relative_to(tree.resolve()) for p in out.stdout.split()):
        raise SystemExit(f"error: the copy's packages do not shadow the installed ones: {out.stdout.strip()}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", help="mutations to run (default: all)")
    ap.add_argument("--list", action="store_true", help="list the mutations and exit")
    ap.add_argument("--source", choices=("worktree", "head"), default="worktree")
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds per test run")
    args = ap.parse_args(argv)
    by_name = {m.name: m for m in MUTATIONS}
    if args.list:
        for m in MUTATIONS:
            print(f"{m.name:28s} {m.path}: {m.why}")
        return 0
    unknown = [n for n in args.names if n not in by_name]
    if unknown:
        print(f"error: unknown mutation {unknown[0]!r} (see --list)", file=sys.stderr)
        return 2
    chosen = [by_name[n] for n in args.names] if args.names else list(MUTATIONS)

    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="accrue-mutation-") as tmp:
        tree = Path(tmp)
        copy_tree(tree, args.source)
        check_imports_from(tree)
        stale = [m.name for m in chosen if (tree / m.path).read_text().count(m.old) != 1]
        if stale:
            print(f"error: snippet of {', '.join(stale)} no longer occurs exactly once: update it", file=sys.stderr)
            return 2
        # the unmutated copy passes every test selection used below (one run per test file)
        for sel in baseline_selections(chosen):
            rc, out = run_tests(tree, sel, args.timeout)
            if rc != 0:
                print(f"error: the unmutated tree fails {' '.join(sel)} (exit {rc}):\n{out}", file=sys.stderr)
                return 2
        survivors, broken = [], []
        for m in chosen:
            path = tree / m.path
            original = path.read_text()
            path.write_text(original.replace(m.old, m.new, 1))
            t0 = time.monotonic()
            try:
                rc, out = run_tests(tree, m.tests, args.timeout)
            finally:
                path.write_text(original)
            verdict = {0: "SURVIVED", 1: "killed"}.get(rc, f"error (pytest exit {rc})")
            print(f"{verdict:10s} {m.name:28s} {time.monotonic() - t0:5.1f} s  {m.why}", flush=True)
            if rc == 0:
                survivors.append(m.name)
            elif rc != 1:
                broken.append(m.name)
                print(out, file=sys.stderr)
    total = time.monotonic() - started
    print(f"{len(chosen) - len(survivors) - len(broken)}/{len(chosen)} killed in {total:.0f} s", flush=True)
    if survivors:
        print(f"error: surviving critical mutations: {', '.join(survivors)}", file=sys.stderr)
        return 1
    if broken:
        print(f"error: mutations that did not run cleanly: {', '.join(broken)}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
