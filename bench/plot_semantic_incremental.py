"""Plot of `semantic_incremental` (crates/pipeline/examples): per semantic pass, the network's
input and its time as the map grows, full passes against incremental ones.

    bench/.venv/bin/python bench/plot_semantic_incremental.py \
        [bench/results/semantic_incremental.json] [docs/images/semantic_incremental.png]

Left: surface cells of the map and cells given to the network per pass. Right: time per pass
read off the network timed alone (lines) and as measured inside the pipeline while the front
end ran on the same cores (faint points).
"""
import json
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    src = sys.argv[1] if len(sys.argv) > 1 else "bench/results/semantic_incremental.json"
    dst = sys.argv[2] if len(sys.argv) > 2 else "docs/images/semantic_incremental.png"
    with open(src) as f:
        data = json.load(f)
    fig, (ax_in, ax_ms) = plt.subplots(1, 2, figsize=(12, 4.4))
    full = data["full"]
    ax_in.plot([p["frame"] for p in full], [p["map_cells"] for p in full], "k--", lw=1, label="map (surface cells)")
    for name, style, color in (("full", "o-", "tab:blue"), ("incremental", "s-", "tab:orange")):
        passes = data[name]
        frames = [p["frame"] for p in passes]
        ax_in.plot(frames, [p["input_cells"] for p in passes], style, ms=3, color=color, label=f"{name}: network input")
        ax_ms.plot(frames, data["estimated_ms"][name], style, ms=3, color=color, label=f"{name} (network alone)")
        ax_ms.plot(frames, [p["network_ms"] for p in passes], ".", color=color, alpha=0.35,
                   label=f"{name} (in pipeline, shared cores)")
    ax_in.set_xlabel("frame (keyframe every 10)")
    ax_in.set_ylabel("5 cm cells")
    ax_ms.set_xlabel("frame (keyframe every 10)")
    ax_ms.set_ylabel("back-end time per pass, ms")
    for ax in (ax_in, ax_ms):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(
        f"{data['scene']}, {data['frames']} frames, network {data['network']}, "
        f"context {data['context_m']} m; final labels agree on {100 * data['agreement']:.1f}% of cells",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(dst, dpi=110)
    print(f"wrote {dst}")


if __name__ == "__main__":
    main()
