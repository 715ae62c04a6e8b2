"""Learning curve of a run from its TensorBoard events: a PNG plot and a Markdown table.

python tools/learning_curve.py runs/mix-20-5-8 [--out docs/learning_curve_mix_20_5_8.png]
"""

from __future__ import annotations

import dataclasses
import struct
from collections import defaultdict
from pathlib import Path

import tyro
from tensorboardX.proto import event_pb2

CURVES = (
    "eval/pursuer_vs_scripted/success_rate",
    "eval/evader_vs_scripted/success_rate",
    "episode/success_rate",
)


def read_scalars(run_dir: Path) -> dict[str, list[tuple[int, float]]]:
    """tag -> [(env_steps, value)] from every event file under `run_dir/tb` (TFRecord framing)."""
    scalars: dict[str, list[tuple[int, float]]] = defaultdict(list)
    for path in sorted((run_dir / "tb").glob("events.out.tfevents.*")):
        data = path.read_bytes()
        pos = 0
        while pos + 12 <= len(data):
            (length,) = struct.unpack("<Q", data[pos : pos + 8])
            record = data[pos + 12 : pos + 12 + length]
            pos += 12 + length + 4
            if len(record) < length:
                break  # a record cut by a kill: ignore the tail
            event = event_pb2.Event.FromString(record)
            for value in event.summary.value:
                scalars[value.tag].append((event.step, value.simple_value))
    return {k: sorted(v) for k, v in scalars.items()}


@dataclasses.dataclass(frozen=True)
class Args:
    run: tyro.conf.Positional[Path]
    out: Path | None = None
    """PNG to write (default: <run>/learning_curve.png)."""


def main() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    args = tyro.cli(Args)
    scalars = read_scalars(args.run)
    # Iterations in which no arena finished carry no episode statistics (older runs logged 0).
    finished = dict(scalars.get("episode/finished", []))
    for tag in list(scalars):
        if tag.startswith("episode/") and tag != "episode/finished":
            scalars[tag] = [(s, v) for s, v in scalars[tag] if finished.get(s, 1) > 0]
    fig, ax = plt.subplots(figsize=(7, 4))
    for tag in CURVES:
        if tag in scalars:
            steps, values = zip(*scalars[tag], strict=True)
            ax.plot(steps, values, marker="o" if tag.startswith("eval") else None, label=tag)
    ax.set_xlabel("env steps")
    ax.set_ylabel("success rate (evaders taken / evaders)")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"{args.run.name}: co-evolution learning curve")
    fig.tight_layout()
    out = args.out or args.run / "learning_curve.png"
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")
    print("| env steps | pursuers vs scripted evader | scripted pursuers vs evader |")
    print("|---|---|---|")
    ev_p = dict(scalars.get(CURVES[0], []))
    ev_e = dict(scalars.get(CURVES[1], []))
    for step in sorted(ev_p):
        print(f"| {step:,} | {ev_p[step]:.3f} | {ev_e.get(step, float('nan')):.3f} |")


if __name__ == "__main__":
    main()
