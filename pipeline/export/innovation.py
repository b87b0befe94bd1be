"""The innovation monitor in the exported code (docs/monitor.md, The innovation monitor).

:class:`qsls.pipeline.control.innovation.InnovationMonitor` written out as C99 and as stdlib
Python with the same operations in the same order, so that the C double build and the Python
module compute the same bits from the same measurements and commands (no fused multiply-add:
``-std=c99`` keeps ``-ffp-contract=off``; Python's floats are IEEE doubles):

- ``nu_c = y'_c - sum_j A_xx[c][j] yp_j - sum_j A_xa[c][j] a_j - sum_j B_x[c][j] du_j`` left to
  right over the nonzero coefficients;
- the loop states ``a <- A_aa a + B_a du``, each row accumulated from 0;
- per checked channel and window, a running sum of the quantized innovations (exact integers
  in doubles, :func:`qsls.pipeline.control.innovation.quantize`: add the newest, subtract the one
  leaving), compared with ``+/- sum_limit``; the median over the channel's shifts is beyond
  the bound when more than ``ns // 2`` of the last ``ns`` sums are on one side, which is
  counted (one comparison per window and tick, no sort: docs/monitor.md, Rounding); a sum not
  yet held counts on neither side, so while the windows fill ``ns // 2 + 1`` of those held
  decide (docs/monitor.md, Deciding before all shifts are held).

Nothing here is used unless the spec is active: a controller without an innovation monitor
exports the code it exported before.
"""

from __future__ import annotations

import numpy as np

from qsls.pipeline.control.innovation import (
    DOUBLE_EPS,
    QUANTUM_MAX,
    QUANTUM_SCALE,
    TRIP_INNOVATION_OUTLIERS,
    TRIP_SUM_CHANNEL,
    TRIP_SUM_WINDOW,
    InnovationSpec,
    innovation_tolerance,
    sum_limit,
)
from qsls.pipeline.core.plant import NX

FLOAT_EPS = 2.0**-24
FLOAT_INNOVATION_RTOL = 1e-5
"""The float build's thresholds are this much wider besides the float rounding bound (its
closed loop is not the double one: a margin, not a proof, as for the envelope)."""


def float_thresholds(spec: InnovationSpec, values: list[float]) -> list[float]:
    """Thresholds for the float build: widened by the float sums' rounding bound and
    :data:`FLOAT_INNOVATION_RTOL`, rounded up to a float32."""
    extra = innovation_tolerance(spec.ring, max(values, default=0.0), FLOAT_EPS)
    out = []
    for v in values:
        if v <= 0:
            out.append(0.0)
            continue
        wide = v * (1.0 + FLOAT_INNOVATION_RTOL) + extra
        f = np.float32(wide)
        if float(f) < wide:
            f = np.nextafter(f, np.float32(np.inf))
        out.append(float(f))
    return out


def stored(spec: InnovationSpec, float_build: bool) -> tuple[list[list[float]], list[float]]:
    """``(window thresholds, outlier thresholds)`` as the build stores them."""
    thr = [list(r) for r in spec.threshold]
    oth = list(spec.outlier_threshold)
    if float_build:
        thr = [float_thresholds(spec, r) for r in thr]
        oth = float_thresholds(spec, oth)
    return thr, oth


def terms(spec: InnovationSpec, c: int) -> list[tuple[str, int, float]]:
    """The nonzero coefficients of channel ``c``'s innovation, in the order they are
    subtracted: ``("yp", j, A_xx)``, ``("a", j, A_xa)``, ``("du", j, B_x)``."""
    out: list[tuple[str, int, float]] = []
    for name, rows in (("yp", spec.a_xx), ("a", spec.a_xa), ("du", spec.b_x)):
        out += [(name, j, float(v)) for j, v in enumerate(rows[c]) if v != 0.0]
    return out


def _shape(spec: InnovationSpec) -> tuple[list[int], int, int, int, int]:
    """``(live channels, ring R = longest window + 1, windows, largest shift, loop states)``."""
    live = spec.live_channels() if spec.windows else []
    return (live, max(spec.windows, default=0) + 1, len(spec.windows),
            max((spec.shifts[c] for c in live), default=1), len(spec.a_aa))  # fmt: skip


def state_fields(spec: InnovationSpec, real: str, real_bytes: int | None = None) -> list[str]:
    """The C struct's innovation fields (none when inactive): the doubles first (the block
    starts 8-aligned), then the reals (type ``real`` of ``real_bytes`` bytes; default: 4 for
    ``float``, else 8), the counters, the bytes, and a pad to 8 bytes."""
    if not spec.active:
        return []
    live, R, nw, ns, na = _shape(spec)
    nl = len(live)
    out = []
    if nl:
        out += [
            f"double inn_q[{nl}][{R}]; /* quantized innovations (integers), newest at inn_head */",
            f"double inn_sum[{nl}][{nw}]; /* running window sums of inn_q (integers) */",
        ]
    out += [
        f"{real} inn_yp[6]; /* the previous accepted tick's gated y */",
        f"{real} inn_du[3]; /* the command flown at the previous tick (deviation) */",
    ]
    if na:
        out.append(f"{real} inn_a[{na}]; /* the attitude loop's states from the commands */")
    if nl:
        out += [
            f"unsigned int inn_above[{nl}][{nw}]; /* of the last ns sums, those above the bound */",
            f"unsigned int inn_below[{nl}][{nw}]; /* ... below minus the bound */",
            f"unsigned int inn_shead[{nl}]; /* next slot of inn_side */",
        ]
    out += [
        "unsigned int inn_head; /* newest innovation's slot */",
        "unsigned int inn_valid; /* consecutive innovations held (saturating) */",
        "unsigned int inn_phead; /* next slot of inn_placed */",
        "unsigned int inn_pcount; /* outlier ticks placed in the ring */",
        "unsigned int inn_last1; /* 1 + the tick of the last placement (0: none) */",
        "unsigned int inn_have_yp; /* inn_yp holds the previous tick's y */",
        "unsigned int inn_started; /* a tick has passed since reset */",
        f"unsigned char inn_placed[{spec.count_window}]; /* outlier ticks placed (ring) */",
    ]
    if nl:
        out.append(f"signed char inn_side[{nl}][{nw}][{ns}]; /* each sum's side: 1, -1, 0 */")
    size = real_bytes if real_bytes is not None else (4 if real == "float" else 8)
    pad = -_raw_bytes(spec, size) % 8
    if pad:
        out.append(f"unsigned char inn_pad[{pad}]; /* the block ends 8-aligned */")
    return out


def _raw_bytes(spec: InnovationSpec, real_bytes: int) -> int:
    live, R, nw, ns, na = _shape(spec)
    nl = len(live)
    doubles = nl * (R + nw)
    ints = 2 * nl * nw + nl + 7
    chars = spec.count_window + nl * nw * ns
    return 8 * doubles + real_bytes * (9 + na) + 4 * ints + chars


def state_bytes(spec: InnovationSpec, real_bytes: int) -> int:
    """The innovation fields' bytes: a block that starts and ends 8-aligned (its doubles
    first, a pad at its end: :func:`state_fields`)."""
    if not spec.active:
        return 0
    raw = _raw_bytes(spec, real_bytes)
    return raw + (-raw % 8)


def c_literal(x: float, float_build: bool) -> str:
    s = f"{float(np.float32(x)):.9g}" if float_build else repr(float(x))
    if not any(ch in s for ch in ".en"):
        s += ".0"
    return f"({s}{'f' if float_build else ''})"


def limits(spec: InnovationSpec, float_build: bool) -> list[list[float]]:
    """Per window and channel the bound on the quantized window sum the build compares with
    (:func:`qsls.pipeline.control.innovation.sum_limit` of its stored threshold; 0: not checked)."""
    thr, _ = stored(spec, float_build)
    return [[sum_limit(t, K) if t > 0 else 0.0 for t in thr[w]] for w, K in enumerate(spec.windows)]


def c_code(spec: InnovationSpec, prefix: str, real: str, float_build: bool) -> str:
    """The C tables and ``PREFIX_innovation_tick(c, yg)`` (yg NULL: a refused tick)."""
    if not spec.active:
        return ""
    live, R, nw, ns_max, na = _shape(spec)
    nl = len(live)
    _, oth = stored(spec, float_build)
    lim = limits(spec, float_build)
    zero = c_literal(0.0, float_build)
    lines = [
        "/* The innovation monitor (docs/monitor.md): window lengths, per window and channel the",
        " * bound on the quantized window sum (integer quanta of 2^-30; 0: not checked), per",
        " * channel the shifts of the median and the per-tick bound beyond which an outlier is",
        " * placed (0: not counted). */",
    ]
    counted = [ch for ch in range(NX) if spec.outlier_threshold[ch] > 0]
    if nl:
        lines.append(
            f"static const unsigned int INN_K[{nw}] = {{ {', '.join(f'{k}u' for k in spec.windows)} }};"
        )
        rows = ",\n    ".join("{ " + ", ".join(repr(float(v)) for v in r) + " }" for r in lim)
        lines.append(f"static const double INN_LIM[{nw}][6] = {{\n    {rows}\n}};")
        lines.append(
            f"static const unsigned int INN_LIVE[{nl}] = {{ {', '.join(f'{c}u' for c in live)} }};"
        )
        lines.append(
            f"static const unsigned int INN_NS[{nl}] = {{ {', '.join(f'{spec.shifts[c]}u' for c in live)} }};"
        )
    if counted:
        lines.append(
            f"static const {real} INN_OTHR[6] = {{ {', '.join(c_literal(v, float_build) for v in oth)} }};"
        )
    body = []
    body.append("    if (c->inn_started != 0u) {")
    body.append("        if (c->inn_have_yp != 0u && yg != NULL) {")
    body.append(f"            {real} nu[6];")
    body.append("            int hit = 0;")
    for ch in range(NX):
        expr = f"yg[{ch}]"
        for name, j, v in terms(spec, ch):
            src = {"yp": "c->inn_yp", "a": "c->inn_a", "du": "c->inn_du"}[name]
            expr += f" - {c_literal(v, float_build)} * {src}[{j}]"
        body.append(f"            nu[{ch}] = {expr};")
    if nl:
        body.append("            fresh = 1;")
        body.append(f"            c->inn_head = (c->inn_head == 0u) ? {R - 1}u : c->inn_head - 1u;")
        body.append(f"            if (c->inn_valid < {max(spec.windows) + ns_max}u) {{")
        body.append("                ++c->inn_valid;")
        body.append("            }")
        body.append(f"            for (l = 0u; l < {nl}u; ++l) {{ /* running sums, exact */")
        body.append(f"                double q = (double)nu[INN_LIVE[l]] * {QUANTUM_SCALE!r};")
        body.append(f"                if (!(q >= -{QUANTUM_MAX!r} && q <= {QUANTUM_MAX!r})) {{")
        body.append(f"                    q = (q < 0.0) ? -{QUANTUM_MAX!r} : {QUANTUM_MAX!r};")
        body.append("                }")
        body.append("                q = trunc(q);")
        body.append("                c->inn_q[l][c->inn_head] = q;")
        body.append(f"                for (w = 0u; w < {nw}u; ++w) {{")
        body.append("                    double acc = c->inn_sum[l][w] + q;")
        body.append("                    if (c->inn_valid > INN_K[w]) {")
        body.append("                        r = c->inn_head + INN_K[w];")
        body.append(f"                        acc = acc - c->inn_q[l][(r >= {R}u) ? r - {R}u : r];")
        body.append("                    }")
        body.append("                    c->inn_sum[l][w] = acc;")
        body.append("                }")
        body.append("            }")
    for ch in counted:
        body.append(
            f"            if (!(nu[{ch}] >= -INN_OTHR[{ch}] && nu[{ch}] <= INN_OTHR[{ch}])) {{"
        )
        body.append("                hit = 1;")
        body.append("            }")
    body.append(
        "            if (hit != 0 && c->inn_last1 != c->mon_ticks) { /* last != tick - 1 */"
    )
    body.append("                placed = 1u;")
    body.append("                c->inn_last1 = c->mon_ticks + 1u;")
    body.append("            }")
    body.append("        } else {")
    if nl:
        body.append("            c->inn_valid = 0u; /* empty windows */")
        body.append("            memset(c->inn_sum, 0, sizeof c->inn_sum);")
        body.append("            memset(c->inn_above, 0, sizeof c->inn_above);")
        body.append("            memset(c->inn_below, 0, sizeof c->inn_below);")
        body.append("            memset(c->inn_side, 0, sizeof c->inn_side);")
    else:
        body.append("            c->inn_valid = 0u;")
    body.append("        }")
    if na:
        body.append(f"        {{ /* a <- A_aa a + B_a du */\n            {real} na_[{na}];")
        for i in range(na):
            expr = zero
            for j in range(na):
                expr += f" + {c_literal(spec.a_aa[i][j], float_build)} * c->inn_a[{j}]"
            for j in range(3):
                expr += f" + {c_literal(spec.b_a[i][j], float_build)} * c->inn_du[{j}]"
            body.append(f"            na_[{i}] = {expr};")
        body.append("            memcpy(c->inn_a, na_, sizeof na_);")
        body.append("        }")
    body.append("    }")
    body.append("    c->inn_pcount -= c->inn_placed[c->inn_phead];")
    body.append("    c->inn_placed[c->inn_phead] = (unsigned char)placed;")
    body.append("    c->inn_pcount += placed;")
    body.append(
        f"    c->inn_phead = (c->inn_phead + 1u == {spec.count_window}u) ? 0u : c->inn_phead + 1u;"
    )
    if counted:
        body.append(f"    if (c->inn_pcount > {spec.m}u) {{")
        body.append(f"        flags |= {TRIP_INNOVATION_OUTLIERS};")
        body.append("    }")
    if nl:
        body.append(f"    for (l = 0u; fresh != 0 && l < {nl}u; ++l) {{")
        body.append("        const unsigned int ns = INN_NS[l], h = c->inn_shead[l];")
        body.append(f"        for (w = 0u; w < {nw}u; ++w) {{")
        body.append("            const double lim = INN_LIM[w][INN_LIVE[l]], v = c->inn_sum[l][w];")
        body.append("            signed char side = 0;")
        body.append("            if (!(lim > 0.0)) {")
        body.append("                continue;")
        body.append("            }")
        body.append("            if (c->inn_valid >= INN_K[w]) {")
        body.append("                side = (signed char)((v > lim) - (v < -lim));")
        body.append("            }")
        body.append("            c->inn_above[l][w] -= (c->inn_side[l][w][h] > 0);")
        body.append("            c->inn_below[l][w] -= (c->inn_side[l][w][h] < 0);")
        body.append("            c->inn_side[l][w][h] = side;")
        body.append("            c->inn_above[l][w] += (side > 0);")
        body.append("            c->inn_below[l][w] += (side < 0);")
        body.append(
            "            if (2u * c->inn_above[l][w] > ns || 2u * c->inn_below[l][w] > ns) {"
        )
        body.append(
            f"                flags |= ({TRIP_SUM_CHANNEL} << INN_LIVE[l]) | ({TRIP_SUM_WINDOW} << w);"
        )
        body.append("            }")
        body.append("        }")
        body.append("        c->inn_shead[l] = (h + 1u == ns) ? 0u : h + 1u;")
        body.append("    }")
    body.append("    if (yg != NULL) {")
    body.append("        memcpy(c->inn_yp, yg, sizeof c->inn_yp);")
    body.append("        c->inn_have_yp = 1u;")
    body.append("    } else {")
    body.append("        c->inn_have_yp = 0u;")
    body.append("    }")
    body.append("    c->inn_started = 1u;")
    body.append("    return flags;")
    decls = ["    int flags = 0;", "    unsigned int placed = 0u;"]
    if nl:
        decls += ["    unsigned int l, w, r;", "    int fresh = 0;"]
    fn = (
        "\n/* The innovation monitor's tick (before the filter bank reads yg; yg NULL: refused).\n"
        " * Reads c->mon_ticks as this tick's index (the envelope monitor advances it after). */\n"
        f"static int {prefix}_innovation_tick({prefix}_t *c, const {real} *yg)\n{{\n"
        + "\n".join(decls)
        + "\n\n"
        + "\n".join(body)
        + "\n}\n"
    )
    return "\n".join(lines) + "\n" + fn


def py_code(spec: InnovationSpec, float_build: bool = False) -> str:
    """The stdlib Python class ``_Innovation`` (the same operations as :func:`c_code`)."""
    if not spec.active:
        return "\n\nclass _Innovation:\n    def __init__(self):\n        pass\n\n    def tick(self, yg, tick):\n        return 0\n\n    def command(self, du):\n        pass\n"
    live, R, nw, ns_max, na = _shape(spec)
    nl = len(live)
    _, oth = stored(spec, float_build)
    lim = limits(spec, float_build)
    counted = [ch for ch in range(NX) if spec.outlier_threshold[ch] > 0]
    nu_lines = []
    for ch in range(NX):
        expr = f"yg[{ch}]"
        for name, j, v in terms(spec, ch):
            expr += f" - ({float(v)!r}) * {name}[{j}]"
        nu_lines.append(f"                n{ch} = {expr}")
    a_lines = []
    for i in range(na):
        expr = "0.0"
        for j in range(na):
            expr += f" + ({float(spec.a_aa[i][j])!r}) * a[{j}]"
        for j in range(3):
            expr += f" + ({float(spec.b_a[i][j])!r}) * du[{j}]"
        a_lines.append(f"                {expr},")
    checks = " or ".join(f"not (-{oth[ch]!r} <= n{ch} <= {oth[ch]!r})" for ch in counted) or "False"
    sums = []
    if nl:
        sums.append("                fresh = True")
        sums.append(f"                self._head = self._head - 1 if self._head > 0 else {R - 1}")
        sums.append(f"                if self._valid < {max(spec.windows) + ns_max}:")
        sums.append("                    self._valid += 1")
        sums.append("                valid, head = self._valid, self._head")
        for idx, ch in enumerate(live):
            sums.append(f"                q = _quantize(n{ch})")
            sums.append(f"                ring, acc = self._q[{idx}], self._sum[{idx}]")
            sums.append("                ring[head] = q")
            for w, K in enumerate(spec.windows):
                r = f"head + {K}"
                sums.append(
                    f"                acc[{w}] = acc[{w}] + q - ring[({r}) % {R}] if valid > {K} else acc[{w}] + q"
                )
    win = []
    for idx, ch in enumerate(live):
        ns = spec.shifts[ch]
        tests = [(w, K, lim[w][ch]) for w, K in enumerate(spec.windows) if lim[w][ch] > 0]
        if not tests:
            continue
        win.append(f"            h = self._shead[{idx}]")
        for w, K, t in tests:
            win.append(f"            v = self._sum[{idx}][{w}]")
            win.append(
                f"            side = ((v > {t!r}) - (v < -{t!r})) if self._valid >= {K} else 0"
            )
            win.append(f"            sides = self._side[{idx}][{w}]")
            win.append(f"            cnt = self._count[{idx}][{w}]")
            win.append("            old = sides[h]")
            win.append("            cnt[0] += (side > 0) - (old > 0)")
            win.append("            cnt[1] += (side < 0) - (old < 0)")
            win.append("            sides[h] = side")
            win.append(f"            if 2 * cnt[0] > {ns} or 2 * cnt[1] > {ns}:")
            win.append(
                f"                flags |= {(TRIP_SUM_CHANNEL << ch) | (TRIP_SUM_WINDOW << w)}"
            )
        win.append(f"            self._shead[{idx}] = 0 if h + 1 == {ns} else h + 1")
    a_block = (
        "            if True:  # a <- A_aa a + B_a du\n"
        "                a, du = self._a, self._du\n"
        "                self._a = [\n" + "\n".join(a_lines) + "\n                ]\n"
        if na
        else ""
    )
    win_block = ("        if fresh:\n" + "\n".join(win)) if win else ""
    return f'''

_trunc = __import__("math").trunc
INNOVATION_WINDOWS = {tuple(spec.windows)!r}
INNOVATION_M = {spec.m}


def _quantize(v):
    x = v * {QUANTUM_SCALE!r}
    if not (-{QUANTUM_MAX!r} <= x <= {QUANTUM_MAX!r}):
        x = -{QUANTUM_MAX!r} if x < 0 else {QUANTUM_MAX!r}
    return float(_trunc(x))


class _Innovation:
    """The innovation monitor (docs/monitor.md): ``tick(yg, tick)`` before the filter bank
    (``yg`` None: a refused tick), ``command(du)`` with the command flown at that tick."""

    def __init__(self):
        self._a = [0.0] * {na}
        self._du = [0.0, 0.0, 0.0]
        self._yp = None
        self._q = [[0.0] * {R} for _ in range({nl})]
        self._head = 0
        self._placed = [0] * {spec.count_window}
        self._phead = 0
        self._pcount = 0
        self._last1 = 0
        self._started = False
        self._restart()

    def _restart(self):
        self._valid = 0
        self._sum = [[0.0] * {nw} for _ in range({nl})]
        self._side = [[[0] * {ns_max} for _ in range({nw})] for _ in range({nl})]
        self._count = [[[0, 0] for _ in range({nw})] for _ in range({nl})]
        self._shead = [0] * {nl}

    def tick(self, yg, tick):
        flags = 0
        placed = 0
        fresh = False
        if self._started:
            if self._yp is not None and yg is not None:
                yp, a, du = self._yp, self._a, self._du
{chr(10).join(nu_lines)}
{chr(10).join(sums)}
                if ({checks}) and self._last1 != tick:
                    placed = 1
                    self._last1 = tick + 1
            else:
                self._restart()
{a_block}        self._pcount += placed - self._placed[self._phead]
        self._placed[self._phead] = placed
        self._phead = (self._phead + 1) % {spec.count_window}
        if {bool(counted)!r} and self._pcount > {spec.m}:
            flags |= {TRIP_INNOVATION_OUTLIERS}
{win_block}
        self._yp = list(yg) if yg is not None else None
        self._started = True
        return flags

    def command(self, du):
        self._du = [float(v) for v in du]
'''


__all__ = ["DOUBLE_EPS", "c_code", "py_code", "state_bytes", "state_fields", "stored"]
