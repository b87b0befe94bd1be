"""The innovation monitor in the exported code (docs/monitor.md, The innovation monitor).

:class:`qsls.pipeline.control.monitor.InnovationMonitor` written out as C99 and as stdlib
Python with the same operations in the same order, so that the C double build and the Python
module compute the same bits from the same measurements and commands (no fused multiply-add:
``-std=c99`` keeps ``-ffp-contract=off``; Python's floats are IEEE doubles):

- ``nu_c = y'_c - sum_j A_xx[c][j] yp_j - sum_j A_xa[c][j] a_j - sum_j B_x[c][j] du_j`` left to
  right over the nonzero coefficients;
- the loop states ``a <- A_aa a + B_a du``, each row accumulated from 0;
- per checked channel, the window sums as differences of the innovations' suffix sums, newest
  first, the median over the channel's shifts, compared with ``+/- threshold``.

Nothing here is used unless the spec is active: a controller without an innovation monitor
exports the code it exported before.
"""

from __future__ import annotations

import numpy as np

from qsls.pipeline.control.monitor import (
    DOUBLE_EPS,
    TRIP_INNOVATION_OUTLIERS,
    TRIP_SUM_CHANNEL,
    TRIP_SUM_WINDOW,
    InnovationSpec,
    innovation_tolerance,
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


def state_fields(spec: InnovationSpec, real: str) -> list[str]:
    """The C struct's innovation fields (none when inactive)."""
    if not spec.active:
        return []
    live, L, na = spec.live_channels(), spec.ring, len(spec.a_aa)
    out = [
        f"{real} inn_yp[6]; /* the previous accepted tick's gated y */",
        f"{real} inn_du[3]; /* the command flown at the previous tick (deviation) */",
    ]
    if na:
        out.append(f"{real} inn_a[{na}]; /* the attitude loop's states from the commands */")
    if live and L:
        out.append(f"{real} inn_nu[{len(live)}][{L}]; /* innovations, newest at inn_head */")
    out += [
        f"unsigned char inn_placed[{spec.count_window}]; /* outlier ticks placed (ring) */",
        "unsigned int inn_head; /* newest innovation's slot */",
        "unsigned int inn_valid; /* consecutive innovations held */",
        "unsigned int inn_phead; /* next slot of inn_placed */",
        "unsigned int inn_pcount; /* outlier ticks placed in the ring */",
        "unsigned int inn_last1; /* 1 + the tick of the last placement (0: none) */",
        "unsigned int inn_have_yp; /* inn_yp holds the previous tick's y */",
        "unsigned int inn_started; /* a tick has passed since reset */",
    ]
    return out


def state_bytes(spec: InnovationSpec, real_bytes: int) -> int:
    """The innovation fields' bytes (before the struct's final padding)."""
    if not spec.active:
        return 0
    live, L, na = spec.live_channels(), spec.ring, len(spec.a_aa)
    reals = 6 + 3 + na + (len(live) * L if live and L else 0)
    chars = spec.count_window
    chars += -chars % 4
    return reals * real_bytes + chars + 7 * 4


def c_literal(x: float, float_build: bool) -> str:
    s = f"{float(np.float32(x)):.9g}" if float_build else repr(float(x))
    if not any(ch in s for ch in ".en"):
        s += ".0"
    return f"({s}{'f' if float_build else ''})"


def c_code(spec: InnovationSpec, prefix: str, real: str, float_build: bool) -> str:
    """The C tables and ``PREFIX_innovation_tick(c, yg)`` (yg NULL: a refused tick)."""
    if not spec.active:
        return ""
    m = prefix.upper()
    live, L, na = spec.live_channels(), spec.ring, len(spec.a_aa)
    thr, oth = stored(spec, float_build)
    zero = c_literal(0.0, float_build)
    nw = len(spec.windows)
    lines = [
        "/* The innovation monitor (docs/monitor.md): window lengths, per window and channel the",
        " * bound on the window sum of innovations (0: not checked), per channel the shifts of the",
        " * median and the per-tick bound beyond which an outlier is placed (0: not counted). */",
    ]
    counted = [ch for ch in range(NX) if spec.outlier_threshold[ch] > 0]
    if nw and live and L:
        lines.append(
            f"static const unsigned int INN_K[{nw}] = {{ {', '.join(f'{k}u' for k in spec.windows)} }};"
        )
        rows = ",\n    ".join(
            "{ " + ", ".join(c_literal(v, float_build) for v in r) + " }" for r in thr
        )
        lines.append(f"static const {real} INN_THR[{nw}][6] = {{\n    {rows}\n}};")
    if counted:
        lines.append(
            f"static const {real} INN_OTHR[6] = {{ {', '.join(c_literal(v, float_build) for v in oth)} }};"
        )
    ns_max = max((spec.shifts[c] for c in live), default=1)
    body = []
    # the innovation, channel by channel
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
    if live and L:
        body.append(f"            c->inn_head = (c->inn_head == 0u) ? {L - 1}u : c->inn_head - 1u;")
        for idx, ch in enumerate(live):
            body.append(f"            c->inn_nu[{idx}][c->inn_head] = nu[{ch}];")
        body.append(f"            if (c->inn_valid < {L}u) {{")
        body.append("                ++c->inn_valid;")
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
    if live and L and nw:
        body.append(f"    for (l = 0u; l < {len(live)}u; ++l) {{")
        body.append("        const unsigned int ch = INN_LIVE[l], ns = INN_NS[l];")
        body.append(f"        {real} acc = {zero};")
        body.append("        r = c->inn_head;")
        body.append("        suf[0] = acc;")
        body.append("        for (i = 0u; i < c->inn_valid; ++i) {")
        body.append("            acc = acc + c->inn_nu[l][r];")
        body.append("            suf[i + 1u] = acc;")
        body.append(f"            r = (r + 1u == {L}u) ? 0u : r + 1u;")
        body.append("        }")
        body.append(f"        for (w = 0u; w < {nw}u; ++w) {{")
        body.append(f"            const {real} thr = INN_THR[w][ch];")
        body.append(f"            {real} med;")
        body.append("            if (!(thr > " + zero + ") || c->inn_valid + 1u < INN_K[w] + ns) {")
        body.append("                continue;")
        body.append("            }")
        body.append(
            "            for (i = 0u; i < ns; ++i) { /* insertion sort of the shifted sums */"
        )
        body.append(f"                const {real} v = suf[INN_K[w] + i] - suf[i];")
        body.append("                j = i;")
        body.append("                while (j > 0u && s[j - 1u] > v) {")
        body.append("                    s[j] = s[j - 1u];")
        body.append("                    --j;")
        body.append("                }")
        body.append("                s[j] = v;")
        body.append("            }")
        body.append("            med = s[ns / 2u];")
        body.append("            if (!(med >= -thr && med <= thr)) {")
        body.append(
            f"                flags |= ({TRIP_SUM_CHANNEL} << ch) | ({TRIP_SUM_WINDOW} << w);"
        )
        body.append("            }")
        body.append("        }")
        body.append("    }")
    body.append("    if (yg != NULL) {")
    body.append("        memcpy(c->inn_yp, yg, sizeof c->inn_yp);")
    body.append("        c->inn_have_yp = 1u;")
    body.append("    } else {")
    body.append("        c->inn_have_yp = 0u;")
    body.append("    }")
    body.append("    c->inn_started = 1u;")
    body.append("    return flags;")
    if live and L:
        lines.append(
            f"static const unsigned int INN_LIVE[{len(live)}] = {{ {', '.join(f'{c}u' for c in live)} }};"
        )
        lines.append(
            f"static const unsigned int INN_NS[{len(live)}] = {{ {', '.join(f'{spec.shifts[c]}u' for c in live)} }};"
        )
    decls = ["    int flags = 0;", "    unsigned int placed = 0u;"]
    if live and L and nw:
        decls += [
            "    unsigned int l, i, j, r, w;",
            f"    {real} suf[{L + 1}];",
            f"    {real} s[{ns_max}] = {{ {zero} }};",
        ]
    fn = (
        f"\n/* The innovation monitor's tick (before the filter bank reads yg; yg NULL: refused).\n"
        f" * Reads c->mon_ticks as this tick's index (the envelope monitor advances it after). */\n"
        f"static int {prefix}_innovation_tick({prefix}_t *c, const {real} *yg)\n{{\n"
        + "\n".join(decls)
        + "\n\n"
        + "\n".join(body)
        + "\n}\n"
    )
    del m
    return "\n".join(lines) + "\n" + fn


def py_code(spec: InnovationSpec, float_build: bool = False) -> str:
    """The stdlib Python class ``_Innovation`` (the same operations as :func:`c_code`)."""
    if not spec.active:
        return "\n\nclass _Innovation:\n    def __init__(self):\n        pass\n\n    def tick(self, yg, tick):\n        return 0\n\n    def command(self, du):\n        pass\n"
    live, L, na = spec.live_channels(), spec.ring, len(spec.a_aa)
    thr, oth = stored(spec, float_build)
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
    win = []
    for idx, ch in enumerate(live):
        ns = spec.shifts[ch]
        tests = [(w, K, thr[w][ch]) for w, K in enumerate(spec.windows) if thr[w][ch] > 0]
        win.append(f"        suf = list(_accumulate(_islice(self._nu[{idx}], valid), initial=0.0))")
        for w, K, t in tests:
            win.append(f"        if valid + 1 >= {K + ns}:")
            if ns == 1:
                win.append(f"            med = suf[{K}] - suf[0]")
            else:
                win.append(
                    f"            med = sorted([suf[{K} + i] - suf[i] for i in range({ns})])[{ns // 2}]"
                )
            win.append(f"            if not (-{t!r} <= med <= {t!r}):")
            win.append(
                f"                flags |= {(TRIP_SUM_CHANNEL << ch) | (TRIP_SUM_WINDOW << w)}"
            )
    store = "\n".join(
        f"                self._nu[{idx}].appendleft(n{ch})" for idx, ch in enumerate(live)
    )
    a_block = (
        "            if True:  # a <- A_aa a + B_a du\n"
        "                a, du = self._a, self._du\n"
        "                self._a = [\n" + "\n".join(a_lines) + "\n                ]\n"
        if na
        else ""
    )
    return f'''

_accumulate = __import__("itertools").accumulate
_islice = __import__("itertools").islice
_deque = __import__("collections").deque
INNOVATION_WINDOWS = {tuple(spec.windows)!r}
INNOVATION_M = {spec.m}


class _Innovation:
    """The innovation monitor (docs/monitor.md): ``tick(yg, tick)`` before the filter bank
    (``yg`` None: a refused tick), ``command(du)`` with the command flown at that tick."""

    def __init__(self):
        self._a = [0.0] * {na}
        self._du = [0.0, 0.0, 0.0]
        self._yp = None
        self._nu = [_deque([0.0] * {max(L, 1)}, maxlen={max(L, 1)}) for _ in range({len(live)})]
        self._valid = 0
        self._placed = [0] * {spec.count_window}
        self._phead = 0
        self._pcount = 0
        self._last1 = 0
        self._started = False

    def tick(self, yg, tick):
        flags = 0
        placed = 0
        if self._started:
            if self._yp is not None and yg is not None:
                yp, a, du = self._yp, self._a, self._du
{chr(10).join(nu_lines)}
{store}
                if self._valid < {L}:
                    self._valid += 1
                if ({checks}) and self._last1 != tick:
                    placed = 1
                    self._last1 = tick + 1
            else:
                self._valid = 0
{a_block}        self._pcount += placed - self._placed[self._phead]
        self._placed[self._phead] = placed
        self._phead = (self._phead + 1) % {spec.count_window}
        if {bool(counted)!r} and self._pcount > {spec.m}:
            flags |= {TRIP_INNOVATION_OUTLIERS}
        valid = self._valid
{chr(10).join(win)}
        self._yp = list(yg) if yg is not None else None
        self._started = True
        return flags

    def command(self, du):
        self._du = [float(v) for v in du]
'''


__all__ = ["DOUBLE_EPS", "c_code", "py_code", "state_bytes", "state_fields", "stored"]
