"""``docs/results.md``'s first section: ``hapticlab bench paper``, the paper's tables beside ours.

Every measured figure in the text is read from the JSON; what is typed here is how the runs were set up
(as ``sessions/bench/paper.py`` sets them up) and what the numbers mean.
"""

from __future__ import annotations

from typing import Any

from hapticlab.sessions.bench.report_markdown import AXES_F, AXES_T, num, table, vec


def paper_section(out: dict[str, Any], figures: str) -> list[str]:
    """``hapticlab bench paper``: the paper's Tables I–III, convergence, indentation, the 104 g mass."""
    setup, paper, conv, ident = out["setup"], out["paper"], out["convergence"], out["identification"]
    lines = [
        "## The paper's experiments, reproduced in simulation",
        "",
        "`hapticlab bench paper` (JSON: `docs/results/paper.json`). The simulated set-up follows the paper:",
        f"sensor at {setup['rate_hz']:g} Hz, a {setup['mass']:g} kg tool whose centre of gravity is "
        f"{1000 * setup['cog_S'][2]:.1f} mm along the sensor's z axis,",
        f"{setup['identification_s']:g} s of random orientations (within {setup['identification_tilt_deg']:g}° "
        f"of vertical) without contact for identification, then {setup['poses']} random poses",
        f"(within {setup['pose_tilt_deg']:g}°), five phantom indentations, and a 104 g mass turned once about the "
        "horizontal instrument's axis at each speed; plus two runs the paper does not show (a log whose rows",
        "repeat, and a drifting bias with repeated contacts). The paper does not publish its tool's mass, its",
        "sensor's bias or noise, or its contact thresholds, so they are taken from its own tables: a bias of",
        f"({vec(setup['bias_force_S'], 2)}) N and ({vec(setup['bias_torque_S'])}) N·m, so the raw readings have "
        'Tables I and II\'s "before" MAE;',
        f"noise of ({vec(setup['noise_force'], 2)}) N and ({vec(setup['noise_torque'], 4)}) N·m per axis, in "
        'proportion to their "after" Std;',
        f"`{setup['estimator']}` thresholds {setup['force_threshold']:g} N and {setup['torque_threshold']:g} N·m. "
        "**The MAE compensation % therefore lands",
        "near the paper's by construction**; what the tables test is that the method reaches the noise floor",
        '(column "Std/noise" ≈ 1).',
        "",
        "**Convergence** (0-based sample index in the identification run; – = never). The paper's flag is",
        '‖Δx‖ < 1e-3; "truth-based" is gravity within 1 % and the force bias within 0.05 N, and staying there.',
        "",
    ]
    lines += table(
        ("stage", "paper's ‖Δx‖ < 1e-3", "samples after force", "information form", "paper", "truth-based"),
        [
            (
                "force",
                num(conv["force_paper"], 0),
                "",
                num(conv.get("force_paper_information"), 0),
                paper["convergence"]["force_paper"],
                num(conv["force_truth"], 0),
            ),
            (
                "torque",
                num(conv["torque_paper"], 0),
                num(conv["torque_paper_after_force"], 0),
                num(conv.get("torque_paper_information"), 0),
                f"{paper['convergence']['torque_paper']} (after force)",
                num(conv["torque_truth"], 0),
            ),
        ],
    )
    lines += conditions_section(out.get("convergence_conditions"), paper["convergence"])
    lines += [f"**Identified parameters** after {ident['samples']} samples:", ""]
    lines += table(
        ("parameter", "estimator", "batch fit, same samples", "truth"),
        [
            (
                f"`{key}` ({unit})",
                *(vec([v * scale for v in ident[src][key]]) for src in ("params", "batch_fit", "truth")),
            )
            for key, scale, unit in (
                ("gravity_force_B", 1, "N"),
                ("bias_force_S", 1, "N"),
                ("cog_S", 1000, "mm"),
                ("bias_torque_S", 1, "N·m"),
            )
        ],
    )
    for group, title, unit in (("force", "Table I: force", "N"), ("torque", "Table II: torque", "N·m")):
        lines += [
            f"**{title} error statistics** ({out['no_contact']['poses']} random poses, {unit}; paper's beside):",
            "",
        ]
        rows = []
        for axis, ours in out["no_contact"][group].items():
            ref = paper["no_contact"][group][axis]
            rows.append(
                (
                    axis,
                    "before",
                    *(num(ours[k]) for k in ("mae_before", "max_before", "std_before")),
                    f"{ours['mae_comp_pct']:.1f} %",
                    "",
                    *(num(ref[k]) for k in ("mae_before", "max_before", "std_before")),
                    f"{ref['mae_comp_pct']:.1f} %",
                )
            )
            rows.append(
                (
                    "",
                    "after",
                    *(num(ours[k]) for k in ("mae_after", "max_after", "std_after")),
                    "",
                    num(ours["std_after_over_noise"], 2),
                    *(num(ref[k]) for k in ("mae_after", "max_after", "std_after")),
                    "",
                )
            )
        lines += table(
            (
                "",
                "",
                "MAE",
                "Max AE",
                "Std",
                "MAE comp.",
                "Std/noise",
                "paper MAE",
                "paper Max AE",
                "paper Std",
                "paper comp.",
            ),
            rows,
            align="llr",
        )
    bounds = out["bounds"]
    lines += [
        "**Table III: compensation error bounds** over the random poses (±, N and N·m). The batch fit and the",
        "frozen `rls` are identified on the tour, then held; the running `rls` keeps learning during the poses,",
        "as the paper's does.",
        "",
    ]
    lines += table(
        ("", "batch fit, held", "rls, frozen", "rls, running", "Yu et al. (paper)", "proposed (paper)"),
        [
            (
                axis,
                num(bounds.get("batch", {}).get(axis)),
                num(bounds.get("rls_frozen", {}).get(axis)),
                num(bounds["rls"][axis]),
                num(paper["bounds"]["yu2021"][axis]),
                num(paper["bounds"]["rls"][axis]),
            )
            for axis in AXES_F + AXES_T
        ],
    )
    ind, r104, low = out["indentation"], out["rotation_104g"], out["rotation_104g_low_noise"]
    lines += [
        f"**Phantom indentation** (Fig. 7, {ind['contacts']} contacts): plateau samples flagged as contact "
        f"{ind['detected_plateau_pct']:.1f} %, free samples flagged {ind['false_contact_pct']:.2f} %;",
        f"RMS between contacts ({vec(ind['rms_free'])}) N, error in contact ({vec(ind['rms_error_in_contact'])}) N.",
        "",
        f"**104 g reference mass** (Figs. 8–9): |contact force| against {r104['load_N']:.2f} N, one turn per speed, "
        f"at Table I's noise ({vec(r104['noise_force'], 3)} N) and at a quarter of it. The paper: MAE ≤ "
        f"{paper['rotation_104g']['72']['mae']:g} N,",
        f"Max AE {paper['rotation_104g']['72']['max_ae']:g} N at 72 deg/s, "
        f"Std < {paper['rotation_104g']['std_max']:g} N.",
        "",
    ]
    speeds = [k for k in r104 if k.isdigit()]
    lines += table(
        ("deg/s", "MAE", "Max AE", "Std", "mean", "MAE, ¼ noise", "Max AE, ¼ noise", "Std, ¼ noise"),
        [
            (
                s,
                *(num(r104[s][k]) for k in ("mae", "max_ae", "std", "mean")),
                *(num(low[s][k]) for k in ("mae", "max_ae", "std")),
            )
            for s in speeds
        ],
    )
    rep, drift = out["repeated_rows"], out["drift_contact"]
    lines += [
        "**What this shows.**",
        "",
        "* Tables I–II: after compensation the Std of every axis is the simulated noise's (Std/noise above); the",
        "  compensation percentages follow from the chosen bias and noise, not from the method.",
        "* Table III: in simulation the model is exact, so a batch fit held after the tour and `rls` reach the",
        "  same force bounds; the paper's columns include what real hardware adds (see the real recordings).",
        "* Convergence: ‖Δx‖ falls roughly as noise/k, so the paper's count says more about the noise than about",
        f"  the method. Truth-based convergence comes at sample {num(conv['force_truth'], 0)}: the tour's first "
        "segment turns about a single axis, leaving one",
        '  direction of [B_f, f0] unobservable while the flag already says "converged" (fig3). The torque stage',
        "  starts then, on a bias that is still wrong, and with no forgetting that error stays: compare the",
        f"  estimator's `cog_S` z ({1000 * ident['params']['cog_S'][2]:.1f} mm) with the batch fit's "
        f"({1000 * ident['batch_fit']['cog_S'][2]:.1f} mm) and the truth ({1000 * ident['truth']['cog_S'][2]:.1f} mm).",
        "  hapticlab's sessions keep the haptic force off until the parameters' std says they are identified.",
        "* The 104 g mass: at Table I's noise the error is noise-bound; Max AE is the extreme of the noise over",
        "  the turn, so it grows with the number of samples (a slow turn has more) and is not comparable with the",
        "  paper's rising Max AE, which it attributes to inertia.",
        f"* Not in the paper, repeated rows ({rep['rows']} rows, 40 poses × 5 identical rows, like the LWR4 logs): "
        f"‖Δx‖ < 1e-3 holds at row {rep['converged_force_at']},",
        f"  then the fixed threshold refuses {rep['refused_pct']:.1f} % of the (contact-free) rows, and the estimate "
        f"stays where the first rows left it (RMS {vec(rep['rms_force_S'])} N).",
        f"* Not in the paper, drift with contacts: the bias drifts {drift['drift_N_per_min']:g} N/min with an "
        f"indentation every 10 s ({drift['duration_s']:g} s);",
        f"  {drift['false_contact_pct']:.1f} % of the contact-free samples are refused as contact, "
        f"{drift['false_contact_last_30s_pct']:.1f} % over the last 30 s, where the free-space",
        f"  RMS is ({vec(drift['rms_free_last_30s'])}) N against a noise of ({vec(drift['noise_force'], 2)}) N "
        "(`drift_contact.png`). The paper's method has no way back",
        "  from this; `kalman`'s drift states are the fix (next section).",
        "",
        f"| ![fig3]({figures}/fig3_force_parameters.png) | ![fig4]({figures}/fig4_torque_parameters.png) |",
        "|---|---|",
        f"| ![fig5]({figures}/fig5_force_compensation.png) | ![fig6]({figures}/fig6_torque_compensation.png) |",
        f"| ![fig7]({figures}/fig7_indentation.png) | ![fig8]({figures}/fig8_rotation_104g.png) |",
        f"| ![fig9]({figures}/fig9_rotation_metrics.png) | ![drift]({figures}/drift_contact.png) |",
        "",
    ]
    return lines


def conditions_section(rows: list[dict[str, Any]] | None, paper: dict[str, int]) -> list[str]:
    """Why the convergence differs from the paper's: the same flag against the tour's pace and the noise."""
    if not rows:
        return []
    from hapticlab.sessions.bench.paper_convergence import CONDITION_S, closest_condition

    forces = [r["force"] for r in rows if r["force"] is not None]
    torques = [r["torque_after_force"] for r in rows if r["torque_after_force"] is not None]
    near = closest_condition(rows, paper["force_paper"], paper["torque_paper"])
    lines = [
        "The paper moves its robot to random orientations at 1 kHz and says neither how fast the orientation",
        "changed nor its sensor's noise; Algorithm 1's flag depends on both: ‖Δx‖ falls as the noise over the",
        "samples seen and rises whenever the motion shows a new direction. The same run, the same `rls`, over",
        f"{CONDITION_S:g} s of the tour at other paces (a new random orientation every 3, 1 or 0.3 s) and noises "
        "(the set-up's, half, a quarter):",
        "",
    ]
    lines += table(
        ("new orientation every", "noise (× the set-up's)", "force converged at", "torque, samples after force"),
        [
            (f"{r['pace_s']:g} s", f"{r['noise_scale']:g}", num(r["force"], 0), num(r["torque_after_force"], 0))
            for r in rows
        ],
        align="r",
    )
    if forces and torques and near is not None:
        lines += [
            f"Across these the force stage converges at samples {min(forces)}–{max(forces)} and the torque stage "
            f"{min(torques)}–{max(torques)} samples after it; the paper's {paper['force_paper']} / "
            f"{paper['torque_paper']} lie among them (nearest: every {near['pace_s']:g} s at "
            f"{near['noise_scale']:g}× the noise, {near['force']} / {near['torque_after_force']}). The set-up keeps",
            "3 s and Table I's noise: its count says more about the experiment's pace and noise than about the",
            "method, and the implementation is Algorithm 1's, number for number (docs/estimators.md, `rls`).",
            "",
        ]
    return lines
