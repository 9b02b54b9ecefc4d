"""Write the small synthetic data sets under tests/data (run once; the output is committed).

They mimic only the file formats of the public data sets (columns, units, layout); every
value is made up here from simple formulas.
"""

from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).parent


def hanyang() -> None:
    run = HERE / "hanyang-uwb-outdoor" / "Dynamic_measurements" / "LOS" / "Trajectory_A" / "Case_1"
    run.mkdir(parents=True, exist_ok=True)
    t0 = 1_700_000_000_000_000_000
    t = np.arange(0.0, 4.0, 0.1)                       # 40 epochs at 10 Hz
    tag = np.stack([1.0 + 2.0 * t, 0.5 * np.sin(t), np.full_like(t, 0.1)], axis=-1)
    pd.DataFrame({"timestamp": (t0 + t * 1e9).astype(float), "x": tag[:, 0], "y": tag[:, 1],
                  "z": tag[:, 2], "heading_degrees": 0.0}).to_csv(run / "trajectory.csv", index=False)
    anchors = {3: (0.0, 4.0, 2.0), 5: (10.0, 4.0, 2.0), 9: (10.0, -4.0, 0.5), 12: (0.0, -4.0, 0.5)}
    for k, (aid, a) in enumerate(anchors.items()):
        ts = t + 0.01 * (k + 1)                       # anchors answer at staggered times
        truth = tag.copy()
        truth[:, 2] += 1.0                             # tag 1 m above the trajectory z
        r = np.linalg.norm(truth - np.array(a), axis=-1) + 0.02 * np.cos(7 * t + k)
        pd.DataFrame({"%time": (t0 + ts * 1e9).astype(np.int64),
                      "field.stamp": (t0 + ts * 1e9).astype(np.int64), "field.id": aid,
                      "field.x": a[0], "field.y": a[1], "field.z": a[2],
                      "field.distanceFromTag": r, "field.rssi": -80.0 - k,
                      "field.rssi_fp": -81.0 - k}).to_csv(run / f"A{aid}.csv", index=False)
    for name, off in (("LS.csv", 0.1), ("ESKF.csv", -0.05)):
        pd.DataFrame({"timestamp": (t0 + t * 1e9).astype(float), "x": tag[:, 0] + off,
                      "y": tag[:, 1] - off, "z": tag[:, 2] + 1.0}).to_csv(run / name, index=False)
    (run / "RMSD_results.txt").write_text("LS RMSE: 0.15 m\nLS RMSE_2d: 0.14\n"
                                          "ESKF RMSE: 0.08 m\nESKF RMSE_2d: 0.07\n")
    hanyang_static()


def hanyang_static() -> None:
    """Two static files (LOS and NLOS, anchor at 125 cm, 4 m): 5 rows and the 6 summary rows."""
    cols = ["timestamp", "Transmission #", "Reception #", "maxNoise", "Distance", "Channel",
            "FirstPathAmp1", "FirstPathAmp2", "FirstPathAmp3", "Max Growth CIR",
            "Rx Preamble Count", "Standard Noise", "RSSI(dBm)", "RSSI_fp(dBm)", "rtd_init",
            "rtd_resp", "resp_rx_ts", "poll_tx_ts", "resp_tx_ts", "poll_rx_ts", "anchor_id"]
    for cond, extra in (("LOS", 0.0), ("NLOS", 0.2)):
        folder = HERE / "hanyang-uwb-outdoor" / "Static_measurements" / cond / "height_125.0cm"
        folder.mkdir(parents=True, exist_ok=True)
        k = np.arange(5)
        dist = np.hypot(4.0, 0.25) + extra + 0.01 * k
        rows = [[1_723_714_114.0 + 0.1 * i, 100 + i, 99 + i, 2000, dist[i], 5, 14000, 14000,
                 7800, 7200, 230, 90, -79.0 - 0.1 * i, -81.0, 7.2e7, 7.2e7, 1.0, 2.0, 3.0, 4.0,
                 12] for i in k]
        lines = [",".join(cols)] + [",".join(str(v) for v in r) for r in rows]
        lines += [f"Distance Mean,{dist.mean()}", "Distance Std,0.01", "RSSI(dBm) Mean,-79.2",
                  "RSSI(dBm) Std,0.1", "RSSI_fp(dBm) Mean,-81.0", "RSSI_fp(dBm) Std,0.0"]
        (folder / "4m.csv").write_text("\n".join(lines) + "\n")


def kolakowski() -> None:
    root = HERE / "kolakowski-ble-fingerprints-2021"
    (root / "calibration").mkdir(parents=True, exist_ok=True)
    (root / "tests").mkdir(parents=True, exist_ok=True)
    anchors = np.array([[0.0, 0.0, 2.0], [6.0, 0.0, 2.2], [3.0, 5.0, 2.5]])
    pd.DataFrame({"id": [1, 2, 3], "x": anchors[:, 0], "y": anchors[:, 1],
                  "z": anchors[:, 2]}).to_csv(root / "anchors.csv", index=False)

    def table(xy, ts0):
        d = np.linalg.norm(xy[:, None, :] - anchors[None, :, :2], axis=-1)
        rss = -50.0 - 20.0 * np.log10(np.maximum(d, 0.3))
        rss[::5, 2] = np.nan                           # some readings missing
        frame = pd.DataFrame({"ts": ts0 + np.arange(len(xy)) * 333_333_333, "x": xy[:, 0],
                              "heading": 0.1 * np.arange(len(xy)), "y": xy[:, 1]})
        for j in range(3):
            frame[f"rssi_{j + 1}"] = np.round(rss[:, j], 3)
        return frame

    gx, gy = np.meshgrid(np.linspace(0.5, 5.5, 6), np.linspace(0.5, 4.5, 4))
    table(np.stack([gx.ravel(), gy.ravel()], -1), 1_600_000_000_000_000_000).to_csv(
        root / "calibration" / "calibration_df.csv")
    s = np.linspace(0, 1, 8)
    table(np.stack([1 + 3 * s, 1 + 2 * s], -1), 1_600_000_100_000_000_000).to_csv(
        root / "tests" / "test_robot_df.csv")


def ujiindoorloc() -> None:
    root = HERE / "ujiindoorloc"
    root.mkdir(parents=True, exist_ok=True)
    aps = np.array([[-7600.0, 4864900.0], [-7560.0, 4864900.0], [-7580.0, 4864940.0],
                    [-7700.0, 4865000.0], [-7400.0, 4864800.0]])

    def table(xy, floor, building, ts0, user, phone):
        d = np.linalg.norm(xy[:, None, :] - aps[None], axis=-1)
        rss = np.round(-40.0 - 20.0 * np.log10(np.maximum(d, 1.0))).astype(int)
        rss[d > 60] = 100                              # 100 = not detected
        frame = pd.DataFrame(rss, columns=[f"WAP{k + 1:03d}" for k in range(len(aps))])
        frame["LONGITUDE"], frame["LATITUDE"] = xy[:, 0], xy[:, 1]
        frame["FLOOR"], frame["BUILDINGID"] = floor, building
        frame["SPACEID"], frame["RELATIVEPOSITION"] = 0 if user == 0 else 101, 0 if user == 0 else 2
        frame["USERID"], frame["PHONEID"] = user, phone
        frame["TIMESTAMP"] = ts0 + 10 * np.arange(len(xy))
        return frame

    gx, gy = np.meshgrid(np.linspace(-7610, -7550, 5), np.linspace(4864880, 4864940, 4))
    grid = np.stack([gx.ravel(), gy.ravel()], -1)
    train = pd.concat([table(grid, 0, 0, 1_370_000_000, 3, 13),
                       table(grid[:4] + 5.0, 1, 0, 1_370_001_000, 3, 13)], ignore_index=True)
    valid = table(np.array([[-7595.0, 4864905.0], [-7570.0, 4864920.0], [-7560.0, 4864890.0]]),
                  0, 0, 1_380_000_000, 0, 14)
    train.to_csv(root / "trainingData.csv", index=False)
    valid.to_csv(root / "validationData.csv", index=False)


if __name__ == "__main__":
    hanyang()
    kolakowski()
    ujiindoorloc()
