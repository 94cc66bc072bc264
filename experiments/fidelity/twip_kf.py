"""Stumfoll §8.1.3 and Fig. 8.13 (twip-dmso, noisy case): DMSO against the Kalman filter with noise."""

from __future__ import annotations

import json
import shlex

from experiments.fidelity.runs import command as _cmd, run as _run
from experiments.fidelity.twip_cells import inside, num, num_ci, row

KF_NAMES = {"kf": "KF prior (same information as the DMSO)", "kf_printed": "(170) as printed",
            "kf_posterior": "KF posterior (one measurement more)"}
# bands per state [m, m/s, rad, rad/s]: "within the bounds of the measurement noise", read as k x the RMS
# measurement error after start-up (the experiment's default is 5x)
BANDS = [("5x noise (default)", None), ("3x noise", [3e-4, 1.8e-2, 2.4e-3, 3.6e-3]),
         ("1x noise", [1e-4, 6e-3, 8e-4, 1.2e-3])]
SENSOR_READINGS = [("Table 7.1 as variances (default)", []),
                   ("gyro sigma_r^2 read as a std (0.0012 deg/s)", ["gyro_var=1.44e-06"]),
                   ("biases stationary at start", ["bias_start=stationary"])]


def kf(args, workdir: str):
    seeds = None if args.quick else args.dmso_seeds
    plan = []
    for bname, band in BANDS:
        sets = [] if band is None else ["band_noise=" + json.dumps(band)]
        plan.append((bname, SENSOR_READINGS[0][0], sets))
    for sname, s in SENSOR_READINGS[1:]:
        plan.append((BANDS[0][0], sname, s))
    runs = []
    for bname, sname, sets in plan:
        cmd = _cmd("twip-dmso", ["cases=[\"noise\"]", "tail_s=16.0", *sets], seeds, args.quick)
        runs.append((bname, sname, cmd, _run(cmd, workdir)["results"]["noise"]))
    L = [
        "## §8.1.3 and Fig. 8.13: DMSO against the Kalman filter with noise",
        "",
        f"Scale: {seeds or '--quick'} noise seeds of the full 20 s at dt = 0.01 s per run (full scale 1000). The "
        "thesis: \"in the tilt rate the Kalman filter takes 1.3 seconds to converge to within the bounds of the "
        "measurement noise, where the DMSO takes .15 seconds. Both filters do end up with equal accuracy after 4 "
        "seconds in all states except the position, where the DMSO provides an estimate error two orders of "
        "magnitude smaller\". Convergence time = first time after which |error| stays inside the band (mean "
        "over seeds, 95% interval; holds when the thesis's time lies inside it); \"after 4 s\" = RMS error over "
        "the last 16 s (`tail_s=16`); equal accuracy = RMS ratio KF / DMSO within [0.5, 2] in x_dot, phi, "
        "phi_dot; two orders of magnitude = the position ratio at least 10^1.5.",
        "",
        "Readings: which KF output is compared (`kf`, `kf_printed`, `kf_posterior`, all in every run), the band "
        "(\"the bounds of the measurement noise\" as 5x, 3x or 1x the RMS measurement error), Table 7.1's gyro "
        "entry as a standard deviation, and walking biases started stationary instead of at zero.",
        "",
        "| band | sensors | estimator | phi_dot convergence (s) | thesis | holds | tail RMS ratio KF/DMSO "
        "x / x_dot / phi / phi_dot | equal after 4 s | position x100 | command |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    rows = []
    for bname, sname, cmd, r in runs:
        dm = r["dmso"]
        c = shlex.join(cmd)
        t, ci = dm["convergence_time_s"]["phi_dot"], dm["convergence_time_s_ci95"]["phi_dot"]
        h = inside(0.15, ci)
        L.append(f"| {bname} | {sname} | DMSO | {num_ci(t, ci, 3)} | 0.15 | {h} | — | — | — | `{c}` |")
        rows.append(row("stumfoll:fig-8.13-dmso-0.15s", f"{bname}; {sname}", "DMSO tilt-rate convergence "
                         "time, noisy case", c, num_ci(t, ci, 3) + " s", "0.15 s", h))
        for k in ("kf", "kf_printed", "kf_posterior"):
            if k not in r:
                continue
            e = r[k]
            t, ci = e["convergence_time_s"]["phi_dot"], e["convergence_time_s_ci95"]["phi_dot"]
            h = inside(1.3, ci)
            ratio = {s: e["rms_error_tail"][s] / dm["rms_error_tail"][s] for s in ("x", "x_dot", "phi", "phi_dot")}
            equal = "yes" if all(0.5 <= ratio[s] <= 2.0 for s in ("x_dot", "phi", "phi_dot")) else "no"
            pos = "yes" if ratio["x"] >= 10**1.5 else "no"
            L.append(f"| {bname} | {sname} | {KF_NAMES[k]} | {num_ci(t, ci, 3)} | 1.3 | {h} | "
                     + " / ".join(num(ratio[s], 3) for s in ("x", "x_dot", "phi", "phi_dot"))
                     + f" | {equal} | {pos} | `{c}` |")
            rd = f"{k}; {bname}; {sname}"
            rows.append(row("stumfoll:fig-8.13-kf-1.3s", rd, "KF tilt-rate convergence time, noisy case", c,
                             num_ci(t, ci, 3) + " s", "1.3 s", h))
            both = "yes" if h == "yes" and inside(0.15, dm["convergence_time_s_ci95"]["phi_dot"]) == "yes" else "no"
            rows.append(row("stumfoll:fig-8.13-both-times", rd, "DMSO 0.15 s and KF 1.3 s tilt-rate "
                             "convergence under the same reading", c,
                             f"DMSO {num_ci(dm['convergence_time_s']['phi_dot'], dm['convergence_time_s_ci95']['phi_dot'], 3)}"
                             f" s, KF {num_ci(t, ci, 3)} s", "0.15 s and 1.3 s", both))
            if bname == BANDS[0][0]:  # the tail ratios do not depend on the band
                rows.append(row("stumfoll:claim-8.1.3-position-equal-after-4s", f"{k}; {sname}", "RMS error KF/DMSO over "
                                 "the last 16 s, x_dot / phi / phi_dot", c,
                                 " / ".join(num(ratio[s], 3) for s in ("x_dot", "phi", "phi_dot")), "equal (ratio 1)",
                                 equal))
                rows.append(row("stumfoll:fig-8.13", f"{k}; {sname}", "position RMS error KF/DMSO over the last "
                                 "16 s", c, num(ratio["x"], 3), "about 100 (two orders of magnitude)", pos))
    return L, rows
