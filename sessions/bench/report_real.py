"""``docs/results.md``'s sections on the real recordings: ``bench real`` and ``discrepancy`` on each file."""

from __future__ import annotations

from typing import Any

from hapticlab.sessions.bench.real import REAL_COLUMNS, table_rows
from hapticlab.sessions.bench.report_markdown import norm, num, table, vec


def real_section(out: dict[str, Any]) -> list[str]:
    """``hapticlab bench real``: every estimator on the real recordings against the offline batch fit."""
    lines = [
        "## Real recordings",
        "",
        "`hapticlab bench real` (JSON: `docs/results/real.json`) over the recordings of `../shared/data/real`.",
        "They are contact-free calibration logs, so every row after an estimator's first convergence is scored,",
        'including the rows it judged a contact (every one a false contact: "contact" gives their share and',
        'count; "held out", the rows `kalman` refused without calling them a contact). "batch, same rows" is',
        'the offline batch fit of the whole file scored over the same rows, and "ratio" the online RMS over it',
        '(below 1: better than the offline fit). "2nd half" scores every estimator over the file\'s second half,',
        "whatever its own convergence flag says. The row `kalman + named effects` runs `kalman` with the effects",
        "`hapticlab discrepancy` names on the same file (fitted on that file: in-sample). `batch` does not gate:",
        'its contact column is for comparison only. "last 70 %" scores force and torque over the file\'s last 70 %',
        "of rows, whatever the flags say: the worst axis's RMS over the batch fit's on the same rows (torque in",
        "N·m, where an estimator whose torque stage has not started writes the raw torque).",
        "",
    ]
    rows = [row for row, _ in table_rows(out, num, vec, name=lambda label: f"`{label}`")]
    lines += table(REAL_COLUMNS, rows, align="llr")
    lines += [
        "The paper's convergence flag is the weak part on these files: on the LWR4 logs the first rows repeat, so",
        "‖Δx‖ < 1e-3 holds at once and means nothing; on the static Axia80 poses every new pose moves the",
        "estimate by more than 1e-3. `kalman` declares convergence when the wrench is known at the tool's current",
        "pose and keeps the haptic force off until the motion has identified the tool (the row",
        "`kalman convergence=identified` has the same estimate, its flag raised only then); its drift states",
        "follow slowly varying model error a constant-bias fit cannot ([estimators.md](estimators.md)).",
        "",
    ]
    return lines + causal_bound(out)


def causal_bound(out: dict[str, Any]) -> list[str]:
    """A sentence for each file where ``kalman``'s last-70 % force is above 1.05x the whole-file fit: what
    ``batch`` run online (the least-squares fit over the rows up to each one, that row included) reaches there,
    the best any estimate that has not seen the later rows gets with the paper's model."""
    said = []
    for name, entry in out.items():
        kalman, online = (entry.get("estimators", {}).get(label, {}) for label in ("kalman", "batch"))
        if max(kalman.get("last_ratio_force", [0.0])) > 1.05 and "last_ratio_force" in online:
            k, b = max(kalman["last_ratio_force"]), max(online["last_ratio_force"])
            said.append(f"`{name}`: `kalman` {k:.2f}x, `batch` online {b:.2f}x")
    if not said:
        return []
    return [
        "Where `kalman`'s last-70 % force is above 1.05x the whole-file fit, `batch` run online (the least-squares",
        "fit over every row up to each one, that row included: what an estimate that has not seen the later rows",
        "reaches with the paper's model) is no closer: " + "; ".join(said) + ". The whole-file fit averages",
        "an effect the model lacks over poses the early rows have not seen yet.",
        "",
    ]


def discrepancy_section(files: dict[str, dict[str, Any]]) -> list[str]:
    """``hapticlab discrepancy`` on each real recording: the effects it names and how far the gap shrinks."""
    lines = [
        "## Missing effects on the real recordings",
        "",
        "`hapticlab discrepancy FILE --json` on each real recording (JSON: `docs/results/discrepancy_<file>.json`):",
        "the paper's model fitted to the file, every effect of the library tested on held-out data, the ones",
        'that gain named and added, and what is left. RMS is the force residual\'s, N; "batch fit" is the',
        "paper's model fitted offline to every usable row ([discrepancy.md](discrepancy.md)).",
        "",
    ]
    rows = []
    for name, d in files.items():
        set_aside = sorted({s["effect"] for s in d["steps"] if s.get("action") == "set_aside"})
        final, batch = d["final"]["rms_force_S"], d["batch_fit"]["rms_force_S"]
        rows.append(
            (
                f"`{name}`",
                d["samples"],
                d["time_base"],
                ", ".join(d["effects"]) or "none",
                ", ".join(set_aside) or "–",
                vec(d["baseline"]["rms_force_S"]),
                vec(final),
                vec(batch),
                num(norm(final) / norm(batch), 2),
            )
        )
    lines += table(
        (
            "file",
            "rows",
            "t is",
            "effects named",
            "set aside",
            "RMS before",
            "RMS after",
            "batch fit",
            "after / batch ‖·‖",
        ),
        rows,
        align="lrlllr",
    )
    lines += [
        "Each step, in order (held-out gain: the reduction of the held-out mean square; structure: the share",
        "of what the model leaves without the effect that it explains):",
        "",
    ]
    steps = []
    for name, d in files.items():
        for s in d["steps"]:
            gain = s.get("evidence", {}).get("heldout_gain")
            share = s.get("structure_share")
            steps.append(
                (
                    f"`{name}`",
                    s.get("round", ""),
                    f"`{s['effect']}`",
                    s.get("action", "").replace("_", " "),
                    "–" if gain is None else f"{100 * gain:.1f} %",
                    "–" if share is None else f"{100 * share:.0f} %",
                    vec(s["rms_force_before"]),
                    vec(s["rms_force_after"]),
                    s.get("summary", ""),
                )
            )
    lines += table(
        ("file", "round", "effect", "action", "held-out gain", "structure", "RMS before", "RMS after", "found"),
        steps,
        align="llllrrrrl",
    )
    return lines
