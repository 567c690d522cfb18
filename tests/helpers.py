"""Test helpers: where the repository is, seeded and physically generated data (no hand-made numbers), and how
the estimators' compiled kernels are compared with their numpy references (the tests of rls's and kalman's
kernels, and of both refusing the same samples), what the tests of a serial haptic master send it, and how a
command line's one-line error is checked."""

from __future__ import annotations

import html as html_module
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from hapticlab.core.types import AlignedSamples, HapticCommand

ROOT = Path(__file__).resolve().parents[1]
"""The repository (the hapticlab package's folder: docs/, firmware/, pyproject.toml); tests find its files from here."""
REAL_DATA = ROOT.parent / "shared" / "data" / "real"
"""The real recordings, beside the repository (the ``real_data`` fixture, tests/conftest.py)."""


def static_model_stream(
    n: int,
    seed: int,
    noise_force: float = 0.0,
    noise_torque: float = 0.0,
    gravity_force_B=(0.12, -0.25, -3.4),
    bias_force_S=(1.0, -0.5, 2.0),
    cog_S=(0.002, -0.001, 0.0435),
    bias_torque_S=(0.03, -0.02, 0.01),
):
    """Samples of the paper's static model (eqs. 16–17) at random orientations.

    Returns (AlignedSamples, truth dict). Orientations are uniformly random
    (strong excitation); noise is Gaussian per axis.
    """
    rng = np.random.default_rng(seed)
    R_EB = Rotation.random(n, random_state=seed).as_matrix().transpose(0, 2, 1)
    gravity_force_B = np.asarray(gravity_force_B, float)
    gravity_S = R_EB @ gravity_force_B
    force_S = gravity_S + bias_force_S + rng.normal(0, noise_force, (n, 3))
    torque_S = np.cross(cog_S, gravity_S) + bias_torque_S + rng.normal(0, noise_torque, (n, 3))
    block = AlignedSamples(
        t_ns=np.arange(n, dtype=np.int64) * 1_000_000,
        force_S=force_S,
        torque_S=torque_S,
        R_EB=R_EB,
        seq=np.arange(n),
        status=np.zeros(n, dtype=np.int64),
        stale=np.zeros(n, dtype=bool),
    )
    truth = {
        "gravity_force_B": gravity_force_B,
        "bias_force_S": np.asarray(bias_force_S, float),
        "cog_S": np.asarray(cog_S, float),
        "bias_torque_S": np.asarray(bias_torque_S, float),
    }
    return block, truth


# --------------------------------------------------------------------------- the estimators' kernels against numpy

KEYS = ("contact_force_S", "contact_torque_S", "contact", "converged_force", "converged_torque")
"""The outputs of ``update_block`` compared: the contact wrench (N, N·m), then the flags."""
ROUNDING = 1e-12
"""How far the kalman kernel and the numpy reference may differ: a few ulp of BLAS rounding (N, N·m; relative for
parameters and covariances). Why, and why the two below: tests/plugins/estimators/kalman/test_kernels.py."""
ROUNDING_NOISE = 1e-10
"""The same with the noise estimated (``noise = "auto"``): the rounding fed back through R into the gain."""
ROUNDING_RATE = 1e-9
"""The same with bias-rate states or a mount estimate: another arithmetic for the same filter."""
GAMMA = {"noise_force": 0.12, "noise_torque": 0.01, "convergence": "covariance"}
"""kalman's options before the defaults estimated the noise: the simulated Gamma's, convergence from P."""


def kernel_tour(duration_s: float) -> AlignedSamples:
    """What the kernels are held to their references on: the simulated physics of ``bench paper`` (SimWorld,
    seed 1, no tool inertia) for ``duration_s`` s at 1 kHz."""
    from hapticlab.plugins.simworld import SimWorld
    from hapticlab.sessions.bench.simulation import simulate

    block, _ = simulate(SimWorld(seed=1, inertia=False), duration_s, 1000.0)
    return block


def run_blocks(est, block, size):
    """``est`` over ``block`` in blocks of ``size`` samples: each of :data:`KEYS`, concatenated."""
    parts = [est.update_block(block.subset(slice(i, i + size))) for i in range(0, len(block), size)]
    return {key: np.concatenate([getattr(p, key) for p in parts]) for key in KEYS}


def kalman_tolerance(options) -> float:
    """How far kalman's kernel and reference may differ with these options (:data:`ROUNDING` and the two after it)."""
    if options.get("bias_rate") or options.get("mount_rotation"):
        return ROUNDING_RATE
    return ROUNDING_NOISE if options.get("noise_force", "auto") == "auto" else ROUNDING


def same(a, b, key: str = "", tol: float = ROUNDING) -> bool:
    """Flags identical; numbers within tol (NaN where the other is NaN)."""
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype.kind in "biu" or key in KEYS[2:]:
        return np.array_equal(a, b)
    return a.shape == b.shape and np.allclose(a, b, rtol=tol, atol=tol, equal_nan=True)


def _same_information(a: dict, b: dict, tol: float) -> bool:
    """The identified rule's information matrices (state()["information"]), within tol of each matrix's largest
    entry: its entries are sums of C^T R^-1 C over every sample (up to ~1e8), off-diagonal ones cancelling to
    ~1, so the rounding of R (:data:`ROUNDING_NOISE`) shows at tol of the matrix's scale, not of each entry. The same
    for the learnt tilt walk's state (state()["tilt"]["walk"]): its windows' sums of R_SB over up to ~1000 samples
    (a mount estimate's rounding in each R_SB adds up there: 3e-8 of −7.5 measured)."""
    return a.keys() == b.keys() and all(np.abs(np.subtract(a[k], b[k])).max() <= tol * np.abs(a[k]).max() for k in a)


def same_tree(a, b, tol: float = ROUNDING) -> bool:
    """params(), cov_diag() and state() of the two: the same keys and flags, numbers within tol."""
    if isinstance(a, dict):
        return (
            isinstance(b, dict)
            and a.keys() == b.keys()
            and all(
                _same_information(a[k], b[k], tol)
                if k == "information"
                else _same_information({k: a[k]}, {k: b[k]}, tol)
                if k == "walk" and a[k] is not None
                else same_tree(a[k], b[k], tol)
                for k in a
            )
        )
    if isinstance(a, (list, tuple)) and a and not isinstance(a[0], (int, float, bool)):
        return isinstance(b, (list, tuple)) and len(a) == len(b) and all(same_tree(x, y, tol) for x, y in zip(a, b))
    if isinstance(a, (bool, str)) or a is None:
        return a == b
    return same(a, b, tol=tol)


# --------------------------------------------------------------------------- a haptic master on the emulator

GUARD_S = 10.0
"""s: a guard against hangs only: a test that waits on the master emulator ends on a condition, never a duration."""
READ_TIMEOUT_S = 1.0
"""s: the ``serial`` plugin's read timeout in tests that are not about timeouts (a loaded machine may stall a reply)."""


def haptic_command(force, enabled=True, t_ns=0) -> HapticCommand:
    """A session's command to the master: ``force`` (N, frame D), with a reason when disabled."""
    return HapticCommand(t_ns, np.asarray(force, dtype=float), enabled, "" if enabled else "test")


def cli_error(capsys, argv: list[str]) -> tuple[str | None, str]:
    """Run the command line in-process; (what is wrong or None, the stderr line): it must exit 2 with one
    stderr line, no traceback and no warning (the command line would print it on stderr)."""
    from hapticlab.sessions.cli import main

    with warnings.catch_warnings(record=True) as caught:
        warnings.resetwarnings()  # the command line's filters: what a user would see on stderr
        for category in (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning):
            warnings.simplefilter("ignore", category)
        code = main(argv)
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    if code != 2:
        return f"exit status {code}", err
    if len(lines) != 1 or "Traceback" in err:
        return f"{len(lines)} lines", err
    if not lines[0].startswith(f"hapticlab {argv[0]}: error: "):
        return "not the error line", err
    if caught:
        return f"warnings: {[str(w.message) for w in caught]}", err
    return None, lines[0]


def one_line_error(capsys, argv: list[str]) -> str:
    problem, line = cli_error(capsys, argv)
    assert problem is None, (problem, line)
    return line


FIT_CHECK = """<script>
window.addEventListener("load", () => {
  const page = document.documentElement, width = page.clientWidth, bad = [];
  if (page.scrollWidth > width) bad.push(`the page is ${page.scrollWidth} px wide`);
  for (const el of document.querySelectorAll("h1, h2, p, img, table, .fit")) {
    const box = el.closest(".fit"), r = (box || el).getBoundingClientRect();
    const name = el.tagName + (el.id ? "#" + el.id : "");
    if (r.left < -0.5 || r.right > width + 0.5) bad.push(`${name} spans ${r.left}-${r.right} px`);
    if (el.tagName === "IMG" && !(el.naturalWidth > 0 && el.getBoundingClientRect().width > 100)) bad.push(name);
  }
  const scrolled = [];
  for (const box of document.querySelectorAll(".fit")) {
    if (box.scrollWidth <= box.clientWidth + 1) continue;
    scrolled.push(box.firstElementChild.id);
    if (!["auto", "scroll"].includes(getComputedStyle(box).overflowX)) bad.push(`${box.firstElementChild.id} cut`);
  }
  const out = parent.document.createElement("pre");  // in the frame's parent, the page --dump-dom prints
  out.id = "fit-check";
  out.textContent = JSON.stringify({width, bad, scrolled});
  parent.document.body.append(out);
});
</script>"""


def _framed(page: str, width: int, script: str = "") -> str:
    """The page in a ``width`` px wide frame (headless Chromium's window is 500 px at least), ``script`` in it."""
    inner = html_module.escape(page.replace("</body>", script + "</body>"), quote=True)
    return (
        "<!DOCTYPE html><html><body style='margin:0'>"
        f"<iframe style='border:0;display:block' width={width} height=3000 srcdoc=\"{inner}\"></iframe></body></html>"
    )


def chromium_fit(chromium: str, page: str, width: int, folder: Path, run_command) -> dict:
    """A review page (HTML text) in headless Chromium at ``width`` px: asserts nothing is cut off (the page never
    wider than the window; every heading, paragraph, image and table box inside it; a box that scrolls, a
    ``fit`` box that may) and that its screenshot is drawn, with text; returns the check (``width``, ``bad``,
    ``scrolled``: the tables that scroll in their box)."""
    import json
    import re

    import matplotlib.image

    flags = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"]
    flags.append(f"--user-data-dir={folder / 'profile'}")
    checked, shown = folder / f"checked-{width}.html", folder / f"page-{width}.html"
    checked.write_text(_framed(page, width, FIT_CHECK))
    shown.write_text(_framed(page, width))
    dom = run_command(
        [*flags, "--window-size=1500,3100", "--dump-dom", checked.as_uri()], "chromium --dump-dom", timeout=120
    ).stdout
    found = re.search(r'<pre id="fit-check">(.*?)</pre>', dom)
    assert found, dom[-500:]
    check = json.loads(found.group(1).replace("&quot;", '"'))
    assert width - 30 < check["width"] <= width and check["bad"] == [], check
    shot = folder / f"page-{width}.png"
    done = run_command(
        [*flags, f"--window-size={width},3000", f"--screenshot={shot}", shown.as_uri()],
        "chromium --screenshot",
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    pixels = matplotlib.image.imread(shot)[..., :3]
    assert pixels.shape[1] == width and pixels.std() > 0.05 and (pixels < 0.5).mean() > 0.01  # drawn, with text
    return check


def as_before_the_offset(src: Path, dst: Path, shift: bool = True) -> Path:
    """``src`` (a recording) copied as hapticlab wrote it before log times were Unix time: every log and publish
    time minus the session's ``clock_offset_ns`` and the offset left out of its metadata (with ``shift`` False,
    the same copy with the times and the offset kept: a control whose chunks are cut as the copy's). The
    schemas, channels, metadata and message bytes are copied as they are, the messages in file order."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    with open(src, "rb") as f, open(dst, "wb") as out:
        reader = make_reader(f)
        summary = reader.get_summary()
        records = list(reader.iter_metadata())
        offset = int(next(r.metadata for r in records if r.name == "hapticlab.session")["clock_offset_ns"])
        writer = Writer(out, chunk_size=128 * 1024, compression=CompressionType.ZSTD)
        writer.start(profile="", library="tests/helpers.py")
        schemas = {i: writer.register_schema(s.name, s.encoding, s.data) for i, s in summary.schemas.items()}
        channels = {
            i: writer.register_channel(c.topic, c.message_encoding, schemas.get(c.schema_id, 0), dict(c.metadata))
            for i, c in summary.channels.items()
        }
        for record in records:
            drop = shift and record.name == "hapticlab.session"
            writer.add_metadata(
                record.name, {k: v for k, v in record.metadata.items() if not (drop and k == "clock_offset_ns")}
            )
        by = offset if shift else 0
        for _, channel, m in reader.iter_messages(log_time_order=False):
            writer.add_message(channels[channel.id], m.log_time - by, m.data, m.publish_time - by, m.sequence)
        writer.finish()
    return dst


FINAL_ZERO = {
    "force_D": [0.0] * 3,
    "enabled": False,
    "reason": "session ended",
    "source_t_ns": None,
    "contact_force_N": None,
    "contact": False,
}
"""The session's final zero command, as recorded."""
