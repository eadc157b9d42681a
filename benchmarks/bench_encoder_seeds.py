"""Do the suite's findings in the quick-encoder scenarios survive another quick encoder?

The suite's heavy-stiff, heavy-medium and transfer-rod scenarios give the autoencoder methods
(paper, akf-pinv, broyden-mfac, oracle) a quick encoder trained for their rod
(`feature.checkpoint: auto`: seeded collection walks, 3,000 shapes, 300 epochs, seed
`rodctl.features.auto.QUICK_SEED`). The three target seeds share that one encoder, so the suite
replicates over targets, not over encoder training. This study trains the same quick encoder
with other seeds (`--encoder-seeds`; the seed moves both the collection walks and the weights'
initialisation), runs those three scenarios of configs/benchmarks/suite.yaml once per encoder
(the suite's three target seeds, 100 targets each, every method; `method_set:
feature.checkpoint` pointing at the encoder), and prints, per scenario and method, steps to
converge against the paper's method under each encoder: the mean difference, its BCa interval
and whether it is significant and replicated within that run. `--reference` adds a column from
a full suite folder's statistics.json (the published run, whose encoder is seed 0).

A run of three scenarios corrects for its own 84 pooled tests, not the full suite's 473, so
its "significant" is a little looser than the published one; the means and intervals compare
directly.

    python benchmarks/bench_encoder_seeds.py [--encoder-seeds 1 2] [--workers 2]
        [--reference results/2026-12-02-replicated-suite] [--out runs/encoder-seeds]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path
from typing import Any

import yaml
from suite_tables import load_statistics

from rodctl.bench.compare import load_compare_config, method_config
from rodctl.bench.suite import scenario_configs
from rodctl.config import ExperimentConfig
from rodctl.config.compare import CompareConfig
from rodctl.training.encoder import quick_config, train_checkpoint

REPO = Path(__file__).resolve().parents[1]
SUITE = REPO / "configs" / "benchmarks" / "suite.yaml"
SCENARIOS = ("heavy-stiff", "heavy-medium", "transfer-rod")


def train(scenario_cfg: Any, seed: int, out: Path) -> Path:
    """The quick encoder of `scenario_cfg`'s rod and camera, trained with `seed` into `out`
    (the recipe of `rodctl.training.auto.auto_checkpoint`, another seed)."""
    path = out / f"quick-seed{seed}.npz"
    if path.is_file():
        return path
    data = quick_config(scenario_cfg).model_dump(mode="json")
    data["seed"] = seed
    data["feature"]["checkpoint"] = None
    ckpt = train_checkpoint(ExperimentConfig.model_validate(data))
    out.mkdir(parents=True, exist_ok=True)
    ckpt.save(path)
    val = (ckpt.metrics.get("validation") or ckpt.metrics["train"])["mean_px"]
    print(f"  trained {path} ({val:.2f} px mean validation error)", flush=True)
    return path


def paper_config(scenario: str) -> Any:
    """The paper method's experiment config in `scenario` (seed 0), as the suite builds it."""
    cfg = load_compare_config(str(SUITE), [])
    runs = scenario_configs(cfg, SUITE.parent, str(SUITE))
    data = next(v for v in runs.values() if v["scenario"] == scenario)
    return method_config(CompareConfig.model_validate(data), "paper")


def suite_for(encoders: dict[str, Path], seed: int, out: Path) -> Path:
    """configs/benchmarks/suite.yaml with only `SCENARIOS`, each scenario's autoencoder methods
    on `encoders[scenario]`, written into `out` (its relative paths are the repository's: the
    study runs from there)."""
    raw = yaml.safe_load(SUITE.read_text(encoding="utf-8"))
    raw["name"] = f"encoder-seed{seed}"
    raw["scenarios"] = {name: raw["scenarios"][name] for name in SCENARIOS}
    for name in SCENARIOS:
        raw["scenarios"][name]["method_set"] = {"feature.checkpoint": str(encoders[name])}
    path = out / f"suite-encoder-seed{seed}.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False), encoding="utf-8")
    return path


def run(config: Path, workers: int, out: Path) -> Path:
    proc = subprocess.run(
        [sys.executable, "-m", "rodctl", "compare", str(config), "--workers", str(workers),
         "--out", str(out), "--quiet"],
        cwd=REPO, capture_output=True, text=True, check=False,
    )  # fmt: skip
    if proc.returncode != 0:
        sys.exit(f"rodctl compare {config} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    return Path(proc.stdout.strip().splitlines()[-1])


def _cell(t: dict[str, Any] | None) -> str:
    if not t or not t.get("n") or t.get("p_adjusted") is None:
        return "—"
    mark = " S" if t.get("significant") else ""
    if mark and t.get("replicated"):
        mark = " R"
    return f"{t['mean']:+.2f} [{t['ci_low']:+.2f}, {t['ci_high']:+.2f}]{mark}"


def table(columns: dict[str, dict[str, Any]]) -> list[str]:
    """Markdown: a row per scenario and method, a column per encoder."""
    first = next(iter(columns.values()))
    methods = list(first["scenarios"][SCENARIOS[0]]["methods"])
    out = [
        "| scenario | method − paper | " + " | ".join(columns) + " |",
        "|---|---|" + "---|" * len(columns),
    ]
    for sc in SCENARIOS:
        for m in methods:
            cells = [
                _cell(s["scenarios"][sc]["methods"][m]["metrics"].get("steps_to_converge"))
                for s in columns.values()
            ]
            out.append(f"| {sc} | {m} | " + " | ".join(cells) + " |")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--encoder-seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--reference", type=Path, help="a full suite folder (its encoder: seed 0)")
    ap.add_argument("--out", type=Path, default=REPO / "runs" / "encoder-seeds")
    args = ap.parse_args()
    out = args.out.resolve()
    configs = {name: paper_config(name) for name in SCENARIOS}
    columns: dict[str, dict[str, Any]] = {}
    if args.reference:
        columns["encoder seed 0 (reference)"] = load_statistics(args.reference)
    for seed in args.encoder_seeds:
        print(f"encoder seed {seed}: training the three quick encoders", flush=True)
        encoders = {n: train(configs[n], seed, out / f"encoders-{n}") for n in SCENARIOS}
        folder = run(suite_for(encoders, seed, out), args.workers, out)
        print(f"  suite: {folder}", flush=True)
        columns[f"encoder seed {seed}"] = load_statistics(folder)
    print("steps to converge, method − paper: mean [BCa 95 %]; R significant and replicated")
    print("on every target seed, S significant only (each run corrected over its own tests)")
    print("\n".join(table(columns)))


if __name__ == "__main__":
    main()
