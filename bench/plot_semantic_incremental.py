"""Plot of `semantic_incremental` (crates/pipeline/examples): per semantic pass, the network's
input and its time against the size of the map, full passes against incremental ones.

    bench/.venv/bin/python bench/plot_semantic_incremental.py \
        [bench/results/semantic_incremental.json] [docs/images/semantic_incremental.png]
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
    fig, (ax_in, ax_ms) = plt.subplots(1, 2, figsize=(11, 4.2))
    for name, style in (("full", "o-"), ("incremental", "s-")):
        passes = data[name]
        map_cells = [p["map_cells"] for p in passes]
        ax_in.plot(map_cells, [p["input_cells"] for p in passes], style, ms=3, label=name)
        ax_ms.plot(map_cells, [p["network_ms"] for p in passes], style, ms=3, label=name)
    ax_in.set_xlabel("surface cells in the map (5 cm)")
    ax_in.set_ylabel("cells given to the network per pass")
    ax_ms.set_xlabel("surface cells in the map (5 cm)")
    ax_ms.set_ylabel("back-end time per pass, ms")
    for ax in (ax_in, ax_ms):
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle(
        f"{data['scene']}, {data['frames']} frames, network {data['network']}, "
        f"context {data['context_m']} m; final labels agree on {100 * data['agreement']:.1f}% of cells"
    )
    fig.tight_layout()
    fig.savefig(dst, dpi=110)
    print(f"wrote {dst}")


if __name__ == "__main__":
    main()
