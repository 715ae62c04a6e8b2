"""The package's layers: data flows config -> scene -> env -> networks -> policy -> play (episode
loops, adapters) -> trainer -> evaluator and viewer -> cli, and no module imports one above it
(docs/design.md, Layout). Every import counts, function-level ones too, so a lazy import cannot
hide a cycle."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "pe_mjx"

# Lower layers never import higher ones; modules of one layer may import each other (no cycles).
LAYERS: dict[str, tuple[str, ...]] = {
    "names": ("names", "_quiet", "interrupts", "outputs", "sizes"),
    "config": ("config", "config_files", "experiment", "eval_config", "paper"),
    "scene": ("scene",),
    "env": (
        "env",
        "outcomes",
        "stages",
        "stages.world",
        "stages.geometry",
        "stages.dynamics",
        "stages.placement",
        "stages.events",
        "stages.rewards",
        "stages.masks",
        "stages.observations",
        "stages.metrics",
        "export",
        "trajectory",
    ),
    "networks": ("networks",),
    # Everything that acts: the one `Policy` type, builtin and learned policies, the store that
    # reads trained ones, the resolver, export and deployment. It reads checkpoints but never
    # imports the trainer.
    "policy": (
        "policy",
        "policy.core",
        "policy.export_loader",
        "policy.shipped",
        "policy.scripted",
        "policy.inference",
        "policy.packed",
        "policy.quiet",
        "policy.store",
        "policy.resolve",
        "policy.export",
        "policy.deploy",
        "policy.ship",
    ),
    "play": (
        "rollout",
        "episodes",
        "match",
        "adapters",
        "adapters.common",
        "adapters.jaxmarl",
        "adapters.pettingzoo",
    ),
    "trainer": (
        "ppo",
        "ppo.losses",
        "ppo.pool",
        "ppo.distributed",
        "ppo.train",
        "ppo.checkpoint",
        "ppo.resumable",
        "ppo.curves",
        "ppo.run_files",
        "ppo.loggers",
        "ppo.run",
    ),
    "apps": (
        "bench",
        "eval_metrics",
        "eval_games",
        "eval_reports",
        "evaluate",
        "plots",
        "ratings",
        "ratings.model",
        "ratings.results",
        "ratings.board",
        "reproduce",
        "viewer",
        "viewer.options",
        "viewer.browser",
        "viewer.guard",
        "viewer.scene",
        "viewer.gui",
        "viewer.live",
        "viewer.replay",
        "viewer.sources",
        "viewer.commands",
        "viewer.recording",
        "viewer.training_view",
        "viewer.app",
    ),
    "cli": (
        "cli",
        "__init__",
        "commands",
        "commands.common",
        "commands.export",
        "commands.plot",
        "commands.rate",
        "commands.ship",
        "commands.train_summary",
        "commands.view",
    ),
}
RANK = {m: i for i, mods in enumerate(LAYERS.values()) for m in mods}


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE).with_suffix("").parts
    if parts[-1] == "__init__" and len(parts) > 1:
        parts = parts[:-1]
    return ".".join(parts)


def imports(path: Path) -> set[str]:
    """The pe_mjx modules `path` imports, anywhere in the file."""
    known = {module_name(p) for p in PACKAGE.rglob("*.py")}
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module == "pe_mjx":
                found |= {a.name for a in node.names if a.name in known}
            elif node.module.startswith("pe_mjx."):
                base = node.module.removeprefix("pe_mjx.")
                subs = {f"{base}.{a.name}" for a in node.names} & known
                found |= subs or {base}
        elif isinstance(node, ast.Import):
            found |= {a.name.removeprefix("pe_mjx.") for a in node.names if a.name[:7] == "pe_mjx."}
    return found


def graph() -> dict[str, set[str]]:
    return {module_name(p): imports(p) - {module_name(p)} for p in PACKAGE.rglob("*.py")}


def test_every_module_has_a_layer():
    assert sorted(set(graph()) - set(RANK)) == []


def test_no_module_imports_a_higher_layer():
    upward = [
        f"{m} ({layer_of(m)}) imports {d} ({layer_of(d)})"
        for m, deps in sorted(graph().items())
        for d in sorted(deps)
        if RANK[d] > RANK[m]
    ]
    assert upward == []


def test_no_import_cycles():
    g = graph()
    state: dict[str, int] = {}
    cycles = []

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for d in sorted(g[m]):
            if state.get(d) == 1:
                cycles.append(" -> ".join([*path[path.index(d) :], d]))
            elif d not in state:
                visit(d, [*path, d])
        state[m] = 2

    for m in sorted(g):
        if m not in state:
            visit(m, [m])
    assert cycles == []


def test_the_checker_sees_an_upward_import(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text(
        "def f():\n    from pe_mjx.viewer.live import LiveRun\n    from pe_mjx import env\n"
    )
    assert imports(bad) == {"viewer.live", "env"}


def layer_of(module: str) -> str:
    return next(name for name, mods in LAYERS.items() if module in mods)
