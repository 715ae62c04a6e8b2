"""The viewer's page: every control, readout and legend, laid out once, and what a browser may
send to each (`guard.GuiGuard` refuses the rest). `app.Viewer` wires the controls to its commands;
nothing here acts.
"""

from __future__ import annotations

from typing import Any

from pe_mjx.config import PRESETS, EnvConfig, get_preset
from pe_mjx.names import BACKENDS, CAUSE_NAMES, TEAMS
from pe_mjx.viewer.guard import MAX_ARENAS, MAX_COUNT, SEED_MAX, GuiGuard, Rule
from pe_mjx.viewer.scene import CAUSE_RGB, TEAM_RGB

MAX_SPEED = 120.0
"""Top of the speed slider, in env steps per second."""


class Controls:
    """The viser handles of the page, by name (buttons, sliders, fields, folders, readouts)."""

    status: Any
    error: Any
    play: Any
    pause: Any
    step: Any
    speed: Any
    max_speed: Any
    trails: Any
    loop: Any
    frame: Any
    scene_folder: Any
    preset: Any
    pursuers: Any
    evaders: Any
    obstacles: Any
    arenas: Any
    backend: Any
    seed: Any
    reset: Any
    apply: Any
    policy_folder: Any
    pursuer_policy: Any
    evader_policy: Any
    deterministic: Any
    load: Any
    att_folder: Any
    att_show: Any
    att_team: Any
    att_arena: Any
    att_agent: Any
    att_info: Any
    record: Any
    export: Any
    record_info: Any
    counters: Any
    training: Any


def build_controls(server: Any, guard: GuiGuard, options: Any, mode: str) -> Controls:
    """Lays the page out for a viewer in `mode` ("live", "replay", "training") started with
    `options` (`app.ViewerOptions`), and registers each control's rule with `guard`."""
    c = Controls()
    gui = server.gui
    c.status = gui.add_markdown("starting...")
    c.error = gui.add_markdown("", visible=False)
    _playback(gui, c, options, mode)
    _scene(gui, c, options, mode)
    with gui.add_folder("Policies", visible=mode == "live") as c.policy_folder:
        c.pursuer_policy = gui.add_text("Pursuer policy", options.pursuers)
        c.evader_policy = gui.add_text("Evader policy", options.evaders)
        c.deterministic = gui.add_checkbox("Greedy", initial_value=options.deterministic)
        c.load = gui.add_button("Load policies")
    with gui.add_folder("Attention", visible=mode != "replay") as c.att_folder:
        c.att_show = gui.add_checkbox("Show attention", initial_value=False)
        c.att_team = gui.add_dropdown("Team", TEAMS, initial_value="pursuer")
        c.att_arena = gui.add_number("Arena", 0, min=0, max=MAX_ARENAS - 1, step=1)
        c.att_agent = gui.add_number("Agent", 0, min=0, max=MAX_COUNT - 1, step=1)
        c.att_info = gui.add_markdown("")
    with gui.add_folder("Record"):
        c.record = gui.add_button("Start recording")
        c.export = gui.add_button("Export replay", visible=mode == "replay")
        c.record_info = gui.add_markdown("")
    # Everything that changes every frame sits below the controls, so a growing table never
    # moves a button under the pointer.
    c.counters = gui.add_markdown("")
    c.training = gui.add_markdown("", visible=mode == "training")
    gui.add_markdown(legend_markdown())
    _register(guard, c)
    return c


def _playback(gui: Any, c: Controls, o: Any, mode: str) -> None:
    with gui.add_folder("Playback"):
        c.play = gui.add_button("Play", icon=None)
        c.pause = gui.add_button("Pause")
        c.step = gui.add_button("Step")
        c.speed = gui.add_slider(
            "Steps/s", min=1.0, max=MAX_SPEED, step=1.0, initial_value=o.speed or MAX_SPEED
        )
        c.max_speed = gui.add_checkbox("Max speed", initial_value=o.speed <= 0)
        c.trails = gui.add_checkbox("Trails", initial_value=o.trails)
        c.loop = gui.add_checkbox("Loop episodes", initial_value=o.loop)
        c.frame = gui.add_slider(
            "Frame", min=0, max=1, step=1, initial_value=0, visible=mode == "replay"
        )


def _scene(gui: Any, c: Controls, o: Any, mode: str) -> None:
    with gui.add_folder("Scene", visible=mode == "live") as c.scene_folder:
        preset = o.preset if o.preset in PRESETS else next(iter(PRESETS))
        cfg = get_preset(preset)
        c.preset = gui.add_dropdown("Preset", tuple(PRESETS), initial_value=preset)
        c.pursuers = gui.add_number(
            "Pursuers", cfg.pursuer.num_agents, min=1, max=MAX_COUNT, step=1
        )
        c.evaders = gui.add_number("Evaders", cfg.evader.num_agents, min=1, max=MAX_COUNT, step=1)
        c.obstacles = gui.add_number(
            "Obstacles", cfg.arena.num_obstacles, min=0, max=MAX_COUNT, step=1
        )
        c.arenas = gui.add_number("Arenas", o.arenas, min=1, max=MAX_ARENAS, step=1)
        c.backend = gui.add_dropdown("Backend", BACKENDS, initial_value=o.backend)
        c.seed = gui.add_number("Seed", o.seed, min=0, max=SEED_MAX, step=1)
        c.reset = gui.add_button("Reset")
        c.apply = gui.add_button("Apply scene")


def _register(guard: GuiGuard, c: Controls) -> None:
    """What a browser may change, and how; every other element is read-only to it."""
    buttons = (c.play, c.pause, c.step, c.reset, c.apply, c.load, c.record, c.export)
    flags = (c.max_speed, c.trails, c.loop, c.deterministic, c.att_show)
    wholes = (c.frame, c.pursuers, c.evaders, c.obstacles, c.arenas, c.seed)
    rules = [
        (Rule("button"), buttons),
        (Rule("bool"), flags),
        (Rule("int"), (*wholes, c.att_arena, c.att_agent)),
        (Rule("choice"), (c.preset, c.backend, c.att_team)),
        (Rule("float"), (c.speed,)),
        (Rule("text"), (c.pursuer_policy, c.evader_policy)),
    ]
    guard.add_all([(handle, rule) for rule, handles in rules for handle in handles])


def counters_markdown(rows: list[dict[str, Any]], config: EnvConfig, label: str = "t") -> str:
    """A Markdown table of `arena_counters` rows (plus totals): time, active agents per team,
    evaders captured, and agents collided per cause (wall / obstacle / teammate / opponent)."""
    causes = [name for code, name in CAUSE_NAMES.items() if name != "capture"]
    p, e = config.pursuer.num_agents, config.evader.num_agents
    lines = [
        f"| arena | {label} (s) | pursuers | evaders | captured | collided w/o/t/o |",
        "|---|---|---|---|---|---|",
    ]

    def line(name: str, time_s: str, row: dict[str, Any], n: int) -> str:
        cells = [
            name,
            time_s,
            f"{row['pursuers']}/{p * n}",
            f"{row['evaders']}/{e * n}",
            str(row["captured"]),
            "/".join(str(row[c]) for c in causes),
        ]
        return "| " + " | ".join(cells) + " |"

    for b, row in enumerate(rows):
        mark = " done" if row.get("done") else ""
        lines.append(line(f"{b}{mark}", f"{row['time']:.1f}", row, 1))
    if len(rows) > 1:
        total = {k: sum(r[k] for r in rows) for k in ("pursuers", "evaders", "captured", *causes)}
        lines.append(line("all", "", total, len(rows)))
    return "\n".join(lines)


def legend_markdown() -> str:
    def swatch(rgb: tuple[int, int, int], text: str) -> str:
        hex_ = "#{:02x}{:02x}{:02x}".format(*rgb)
        return f'<span style="color:{hex_}">&#9679;</span> {text}'

    parts = [swatch(TEAM_RGB[t], f"{t}s") for t in TEAMS]
    parts.append(swatch((150, 150, 150), "incapacitated; marker above it:"))
    parts += [swatch(rgb, CAUSE_NAMES[code]) for code, rgb in CAUSE_RGB.items()]
    return " &nbsp; ".join(parts)


__all__ = ["MAX_SPEED", "Controls", "build_controls", "counters_markdown", "legend_markdown"]
