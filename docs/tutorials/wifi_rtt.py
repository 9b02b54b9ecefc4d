"""Your own log, walk-through: WiFi RTT ranges with a bias per access point (3 venues).

Run:  python docs/tutorials/wifi_rtt.py [OUT_DIR] [--small]
Needs the data set (`radioloc datasets fetch wifi-rtt`). Writes the table of
docs/generated/wifi_rtt.md (the page includes it) to OUT_DIR/wifi_rtt.md.

Every number comes from `radioloc` commands, as a user would type them:

    radioloc datasets export wifi-rtt --venue Canteen --circle 1 --out canteen-1
    radioloc locate canteen-1/measurements.csv --anchors canteen-1/anchors.csv \\
        --method ekf-track -o anchor_bias=1 -o range_std_m=1.5 \\
        --reference canteen-1/reference.csv --out canteen-1/track.csv

The baseline is per-epoch least-squares multilateration on the raw ranges (`gn`).

Variant rows, each scored beside the tracker it extends:

- `ekf-track + RSS, self-calibrated`: each access point's log-distance RSS model (mean at
  1 m, exponent, spread) is fitted on the RSS against the distances from the RTT-only track
  above (no truth; :func:`radioloc.locate.path_loss.fit_path_loss`), written as columns of
  the anchors file, and `ekf-track` runs on the ranges and the RSS together:

      radioloc datasets export wifi-rtt --venue Canteen --circle 1 --rss --out canteen-1/rss
      fit_path_loss(read_measurements("canteen-1/rss/measurements.csv"),
                    pd.read_csv("canteen-1/track.csv"), read_anchors("canteen-1/anchors.csv")
                    ).to_csv("canteen-1/anchors_rss.csv", index=False)          # Python
      radioloc locate canteen-1/rss/measurements.csv --anchors canteen-1/anchors_rss.csv \\
          --method ekf-track -o anchor_bias=1 -o range_std_m=1.5 --out canteen-1/rss.csv

- `ekf-track + phone-to-phone, aligned on the tracks`: the phone-to-phone RTT log has a
  clock of its own; its offset (and the range's bias) is taken where the range correlates
  best with the distance between the two RTT-only tracks
  (:func:`radioloc.locate.cooperative.align_peer_ranges`, no truth), its rows are added to
  the log as ranges from M1 to M2, and `ekf-track -o cooperative=1` uses them.

- `ekf-track + heading (IMU azimuth)`: each phone's azimuth is written as `heading` rows
  (the direction of the walk, an IMU input); its offset to the map's frame is the circular
  mean of the azimuth minus the direction of the RTT-only track above, one per phone and
  circle (:func:`radioloc.locate.heading_offset.estimate_heading_offset`, no truth):

      radioloc datasets export wifi-rtt --venue Canteen --circle 1 --heading --out canteen-1/heading
      log = read_measurements("canteen-1/heading/measurements.csv")
      remove_heading_offset(log, estimate_heading_offset(log, pd.read_csv("canteen-1/track.csv"))
                            ).to_csv("canteen-1/heading/map.csv", index=False)     # Python
      radioloc locate canteen-1/heading/map.csv --anchors canteen-1/anchors.csv \\
          --method ekf-track -o anchor_bias=1 -o range_std_m=1.5 --out canteen-1/heading.csv
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.cli import app
from radioloc.io import datasets
from radioloc.io.logs import read_anchors, read_measurements
from radioloc.io.wifi_rtt import VENUES, circles, load_peer_ranges
from radioloc.locate.cooperative import align_peer_ranges
from radioloc.locate.heading_offset import estimate_heading_offset, remove_heading_offset
from radioloc.locate.path_loss import fit_path_loss

#: The tracker's options: ranges biased per AP (anchor_bias), WiFi RTT noise of about 1.5 m.
TRACKER = ("-o", "anchor_bias=1", "-o", "range_std_m=1.5")
#: The published obvious baseline (per-epoch least squares on raw ranges), mean 2-D error.
BASELINE_M = {"Canteen": 2.82, "Conference Room": 7.19, "Library": 4.28}
#: The variant with RSS, and the row it extends (its gain or loss is against that row).
RSS_VARIANT = "ekf-track + RSS, self-calibrated"
PEER_VARIANT = "ekf-track + phone-to-phone, aligned on the tracks"
HEADING_VARIANT = "ekf-track + heading (IMU azimuth)"
BASE_OF = {RSS_VARIANT: "ekf-track", PEER_VARIANT: "ekf-track", HEADING_VARIANT: "ekf-track"}


def radioloc(*args) -> None:
    """Run a `radioloc ...` command in this process (the same as typing it in a shell)."""
    app([str(a) for a in args], standalone_mode=False)


def errors(track: Path, reference: Path) -> np.ndarray:
    """2-D errors of a locate output at the reference's rows (same time and node)."""
    est = pd.read_csv(track)
    ref = pd.read_csv(reference)
    m = est.merge(ref, on=["time", "node"], suffixes=("", "_ref"))
    return np.hypot(m.x - m.x_ref, m.y - m.y_ref).to_numpy()


def main(out: str | Path = "tutorial-wifi-rtt", small: bool = False) -> pd.DataFrame:
    out = Path(out)
    root = datasets.require("wifi-rtt-haiyaoyu")
    rows = []
    for venue in VENUES:
        errs = {"gn": [], "ekf-track": [], "ekf-track --smooth": [], RSS_VARIANT: [],
                PEER_VARIANT: [], HEADING_VARIANT: []}
        for circle in circles(root, venue)[: 1 if small else None]:
            run = out / f"{venue.replace(' ', '-').lower()}-{circle}"
            # 1. Convert one circle (both phones, nodes M1 and M2) to the locate schema.
            radioloc("datasets", "export", "wifi-rtt", "--venue", venue, "--circle", circle,
                     "--out", run)
            log, anchors, ref = run / "measurements.csv", run / "anchors.csv", run / "reference.csv"
            # 2. The baseline, and the tracker with a bias per AP, causal and smoothed.
            radioloc("locate", log, "--anchors", anchors, "--method", "gn", "-o",
                     "on_degenerate=skip", "--quiet", "--out", run / "gn.csv")
            radioloc("locate", log, "--anchors", anchors, "--method", "ekf-track", *TRACKER,
                     "--quiet", "--out", run / "ekf.csv")
            radioloc("locate", log, "--anchors", anchors, "--method", "ekf-track", *TRACKER,
                     "--smooth", "--quiet", "--out", run / "ekf_smooth.csv")
            # 3. RSS added: each access point's path loss fitted against the RTT-only track.
            radioloc("datasets", "export", "wifi-rtt", "--venue", venue, "--circle", circle,
                     "--rss", "--out", run / "rss")
            rss_log = run / "rss" / "measurements.csv"
            fit_path_loss(read_measurements(rss_log), pd.read_csv(run / "ekf.csv"),
                          read_anchors(anchors)).drop(columns="line").to_csv(
                run / "anchors_rss.csv", index=False)
            radioloc("locate", rss_log, "--anchors", run / "anchors_rss.csv", "--method",
                     "ekf-track", *TRACKER, "--quiet", "--out", run / "ekf_rss.csv")
            errs[RSS_VARIANT].append(errors(run / "ekf_rss.csv", ref))
            # 4. Phone-to-phone ranges: their clock aligned on the RTT-only tracks.
            peer = load_peer_ranges(root, venue, circle)
            fit = align_peer_ranges(peer.time_s, peer.range_m, pd.read_csv(run / "ekf.csv"),
                                    "M1", "M2")
            meas = pd.read_csv(log)
            p2p = pd.DataFrame({"time": (peer.time_s + fit["offset_s"]).round(6), "node": "M1",
                                "peer": "M2", "kind": "range",
                                "value": peer.range_m - fit["bias_m"]})
            p2p = p2p[(p2p.value > 0) & p2p.time.between(meas.time.min(), meas.time.max())]
            (run / "coop").mkdir(exist_ok=True)
            pd.concat([meas, p2p]).sort_values(["time", "node"], kind="stable").to_csv(
                run / "coop" / "measurements.csv", index=False)
            radioloc("locate", run / "coop" / "measurements.csv", "--anchors", anchors,
                     "--method", "ekf-track", *TRACKER, "-o", "cooperative=1", "--quiet",
                     "--out", run / "ekf_coop.csv")
            errs[PEER_VARIANT].append(errors(run / "ekf_coop.csv", ref))
            # 5. The phones' azimuth as heading rows, turned into the map by the RTT-only track.
            radioloc("datasets", "export", "wifi-rtt", "--venue", venue, "--circle", circle,
                     "--heading", "--out", run / "heading")
            head = read_measurements(run / "heading" / "measurements.csv").drop(columns="line")
            remove_heading_offset(head, estimate_heading_offset(head, pd.read_csv(run / "ekf.csv"))
                                  ).to_csv(run / "heading" / "map.csv", index=False)
            radioloc("locate", run / "heading" / "map.csv", "--anchors", anchors, "--method",
                     "ekf-track", *TRACKER, "--quiet", "--out", run / "ekf_heading.csv")
            errs[HEADING_VARIANT].append(errors(run / "ekf_heading.csv", ref))
            for key, name in (("gn", "gn.csv"), ("ekf-track", "ekf.csv"),
                              ("ekf-track --smooth", "ekf_smooth.csv")):
                errs[key].append(errors(run / name, ref))
        for key, parts in errs.items():
            e = np.concatenate(parts)
            rows.append({"venue": venue, "method": key, "epochs": e.size, "mean_m": e.mean(),
                         "median_m": np.median(e), "p90_m": np.percentile(e, 90)})
    table = pd.DataFrame(rows)
    (out / "wifi_rtt.md").write_text(snippet(table, small))
    return table


def snippet(table: pd.DataFrame, small: bool) -> str:
    """The markdown table of the docs page."""
    lines = ["<!-- generated by docs/tutorials/wifi_rtt.py; do not edit -->",
             f"Circles: {'the first of each venue' if small else 'all'}; both phones; 2-D error "
             "against the ground truth at every epoch.", "",
             "| venue | method | epochs | mean | median | p90 | mean vs the published baseline "
             "| variant: mean vs the row it extends |",
             "|---|---|---|---|---|---|---|---|"]
    means = {(r.venue, r.method): r.mean_m for r in table.itertuples()}
    for r in table.itertuples():
        base = BASELINE_M[r.venue]
        gain = ""
        if r.method in BASE_OF:
            ref = means[(r.venue, BASE_OF[r.method])]
            gain = f"{r.mean_m - ref:+.2f} m ({100 * (r.mean_m / ref - 1):+.0f} %) vs `{BASE_OF[r.method]}`"
        lines.append(f"| {r.venue} | `{r.method}` | {r.epochs:,} | {r.mean_m:.2f} m | "
                     f"{r.median_m:.2f} m | {r.p90_m:.2f} m | {100 * (r.mean_m / base - 1):+.0f} % "
                     f"(baseline {base:.2f} m) | {gain} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--small"]
    print(main(args[0] if args else "tutorial-wifi-rtt", small="--small" in sys.argv)
          .to_string(index=False))
