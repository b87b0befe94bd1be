"""A shared controller folder is safe to export (issue 50, item 1): a controller name that is
not a plain name is refused in one line; every other certificate text (a status reason,
calibration conditions, the disturbance source) reaches the generated C and Python only as
escaped text inside a comment, a string or the docstring. Nothing in it runs (the export's
self-check executes the module) and nothing compiles in (the library's symbols are the
seven of the interface; the preprocessed source holds the payload nowhere but in strings)."""

from __future__ import annotations

import ast
import dataclasses
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.control.artifacts import CONTROLLER_NAME, load_controller_dir
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.export.bank import export_bank, facts
from qsls.pipeline.export.c import c_files
from qsls.pipeline.export.cbuild import STRICT
from qsls.pipeline.export.python import load_module, module
from qsls.pipeline.export.stage import ExportOptions, export
from tests.controllerfixtures import gated

RUN = CliRunner()
SYMBOLS = {f"qsls_ctrl_{f}" for f in
           ("size", "reset", "step", "trips", "refused", "first_trip", "attitude", "flown")}  # fmt: skip
MARK = "PWNED"


def invoke(*args):
    return RUN.invoke(app, [str(a) for a in args])


def payloads(trap: Path) -> list[str]:
    """Texts that, written unescaped, run code in the Python module (create ``trap/...`` or
    end the self-check) or compile code into the C library (a function, a macro, a trigraph
    line splice), each holding :data:`MARK`."""
    return [
        f'a"""\nimport pathlib; pathlib.Path(r"{trap}", "{MARK}_py").write_text("1")\n"""',
        f'b\\"""; raise SystemExit(\'{MARK}_exit\') #',
        f"c'''\nraise SystemExit('{MARK}_single')\n'''",
        f"*/\nint {MARK}_c(void) {{ return 42; }}\n/*",
        f"d ??/\n*/ int {MARK}_tri(void) {{ return 1; }} /* ??= ??' \\",
        f"e\r\n#define qsls_ctrl_step {MARK}_def\n",
        f"\u202e*/ int {MARK}_bidi; /*\u2066 \x00 \x1b[2J",
        f'f*/ static const char *s = "{MARK}_str"; /*',
    ]


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    """A certified controller folder written by the fixtures (the quickstart's shape)."""
    return gated(tmp_path_factory.mktemp("hostile") / "l1_gated", radius=1.0).folder


def hostile_copy(good: Path, where: Path, name: str = "l1_gated", **edit) -> Path:
    """``good`` copied to ``where/name`` with its certificate's keys replaced (``edit``;
    nested keys as ``a__b``)."""
    folder = where / name
    shutil.copytree(good, folder)
    f = folder / "certificate.yaml"
    cert = yaml.safe_load(f.read_text())
    for key, value in edit.items():
        d = cert
        *path, last = key.split("__")
        for p in path:
            d = d[p]
        d[last] = value
    f.write_text(yaml.safe_dump(cert, sort_keys=False))
    return folder


def strip_c_strings(text: str) -> str:
    return re.sub(r'"(?:[^"\\\n]|\\.)*"', '""', text)


def assert_inert_c(files: dict[str, str], work: Path, gcc: str, n_marks: int) -> None:
    """The C files compile with the strict flags into a library whose symbols are exactly the
    interface's, and the preprocessor's view of them (comments gone, trigraphs and line splices
    applied, every macro kept with -dD) holds the payload only inside string literals."""
    work.mkdir()
    for name, text in files.items():
        (work / name).write_text(text)
    text = "".join(files.values())
    assert text.count(MARK) >= n_marks  # the texts are there (as escaped text)
    lib = work / "lib.so"
    cmd = [gcc, *STRICT, "-O2", "-fPIC", "-shared", "-o", lib, work / "qsls_ctrl.c", "-lm"]
    res = subprocess.run([str(c) for c in cmd], capture_output=True, text=True)
    assert res.returncode == 0 and res.stderr == "", res.stderr
    nm = shutil.which("nm")
    if nm is not None:
        out = subprocess.run([nm, "-D", "--defined-only", str(lib)], capture_output=True,
                             text=True, check=True).stdout  # fmt: skip
        defined = {ln.split()[-1] for ln in out.splitlines() if ln.split()[1:2] != ["w"]}
        assert defined - {"_init", "_fini"} == SYMBOLS, defined
    import ctypes

    so = ctypes.CDLL(str(lib))
    assert all(hasattr(so, s) for s in SYMBOLS)
    assert not any(hasattr(so, f"{MARK}_{s}") for s in ("c", "tri", "bidi", "def"))
    pre = subprocess.run([gcc, "-std=c99", "-E", "-dD", "-P", str(work / "qsls_ctrl.c")],
                         capture_output=True, text=True, check=True).stdout  # fmt: skip
    assert MARK not in strip_c_strings(pre)
    # every #define line is one line: nothing was injected after a newline
    for ln in files["qsls_ctrl.h"].splitlines():
        if ln.startswith("#define"):
            assert MARK not in strip_c_strings(ln).split("/*")[0], ln


def assert_inert_py(text: str, trap: Path) -> Any:
    """The module parses to its docstring plus code that holds no payload; executing it runs
    none (no file in ``trap``, no exit)."""
    tree = ast.parse(text)
    doc = tree.body[0]
    assert isinstance(doc, ast.Expr) and isinstance(doc.value, ast.Constant)
    assert MARK in doc.value.value

    class Blank(ast.NodeTransformer):  # a payload inside a string constant is data
        def visit_Constant(self, node: ast.Constant) -> ast.Constant:
            return ast.Constant("") if isinstance(node.value, str) else node

    rest = ast.Module(body=tree.body[1:], type_ignores=[])
    assert MARK not in ast.unparse(Blank().visit(rest))
    mod = load_module(text)
    assert not list(trap.iterdir())
    return mod


def test_controller_names():
    for ok in ("l1_robust", "l1_robust_imitation", "pd", "l1_nominal", "h2_robust_imitation",
               "l1_robust_paper", "l1_gated", "_x", "a.b-c", "a" * 64):  # fmt: skip
        assert CONTROLLER_NAME.fullmatch(ok), ok
    for bad in ("", "1abc", "a b", 'x"""', "a*/b", "a\nb", "a" * 65, "caf\u00e9", "..", ".x",
                "-x", "a/b", "a??/", "a\u202e"):  # fmt: skip
        assert not CONTROLLER_NAME.fullmatch(bad), bad


def _one_line_error(res, *words):
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.output
    assert "Traceback" not in res.output
    for w in words:
        assert w in lines[0], lines[0]


@pytest.mark.parametrize("target", ["python", "c"])
def test_a_hostile_name_is_refused_in_one_line(tmp_path, good, target):
    trap = tmp_path / "trap"
    trap.mkdir()
    evil = payloads(trap)
    # the certificate's controller: refused wherever the folder is loaded
    folder = hostile_copy(good, tmp_path / "cert", controller=evil[0] if target == "python"
                          else evil[3])  # fmt: skip
    with pytest.raises(InputError, match="is not a controller name"):
        load_controller_dir(folder)
    res = invoke("export", folder, "-t", target, "--out", tmp_path / "o1", "--allow-uncertified")
    _one_line_error(res, "controller", "is not a controller name")
    assert not (tmp_path / "o1").exists()
    # the folder's own name (a name may hold anything but '/'): refused on export
    name = 'l1"""\nopen("PWNED","w")\n"""' if target == "python" else "l1*/ int PWNED_c; /*"
    folder = hostile_copy(good, tmp_path / "dir", name=name)
    res = invoke("export", folder, "-t", target, "--out", tmp_path / "o2")
    _one_line_error(res, "the controller folder's name", "is not a controller name")
    assert not (tmp_path / "o2").exists() and not list(trap.iterdir())
    with pytest.raises(InputError, match="folder's name"):
        facts(load_controller_dir(folder))


@pytest.fixture(scope="module")
def hostile_texts(good, tmp_path_factory):
    """``good`` with every free text of its certificate hostile: relaxed with a status reason
    (in the header's first line), the calibration's conditions (key and value) and the
    disturbance's source."""
    where = tmp_path_factory.mktemp("texts")
    trap = where / "trap"
    trap.mkdir()
    evil = payloads(trap)
    folder = hostile_copy(
        good, where, status="relaxed", status_reason=" | ".join(evil),
        calibration__conditions={evil[0]: evil[3], "perception": " ".join(evil[4:])},
        premise__eps_w_source=evil[1] + evil[5],
    )  # fmt: skip
    return folder, trap, len(evil)


def test_hostile_texts_export_inert_through_the_cli(tmp_path, hostile_texts, gcc):
    folder, trap, n = hostile_texts
    res = invoke("export", folder, "-t", "python", "--out", tmp_path / "py", "--allow-uncertified")
    assert res.exit_code == 0, res.output  # its self-check executed the module: nothing ran
    text = (tmp_path / "py" / "qsls_ctrl.py").read_text()
    assert text.splitlines()[0].startswith('"""NOT CERTIFIED (status relaxed')
    assert_inert_py(text, trap)
    res = invoke("export", folder, "-t", "c", "--out", tmp_path / "c", "--allow-uncertified",
                 "--verify-ticks", 50)  # fmt: skip
    assert res.exit_code == 0, res.output
    files = {p.name: p.read_text() for p in (tmp_path / "c").glob("qsls_ctrl.*")}
    assert files["qsls_ctrl.h"].startswith("/* NOT CERTIFIED (status relaxed")
    assert_inert_c(files, tmp_path / "build", gcc, n)
    assert not list(trap.iterdir())


def test_hostile_texts_export_inert_through_the_library(tmp_path, hostile_texts, gcc):
    folder, trap, n = hostile_texts
    opts = dict(allow_uncertified=True, verify_ticks=50, closed_loop_ticks=50)
    for prec in ("double", "float"):
        r = export(folder, ExportOptions(target="c", precision=prec, **opts), tmp_path / prec)
        assert r.results["verify"]["max_abs_diff"] <= 1e-12
        files = {p.name: p.read_text() for p in (tmp_path / prec).glob("qsls_ctrl.*")}
        assert_inert_c(files, tmp_path / f"build_{prec}", gcc, n)
    r = export(folder, ExportOptions(target="python", **opts), tmp_path / "py")
    assert r.results["verify"]["max_abs_diff"] <= 1e-12
    assert_inert_py((tmp_path / "py" / "qsls_ctrl.py").read_text(), trap)


@pytest.mark.parametrize("which", ["statement", "everything"])
def test_every_text_a_generated_file_states_is_escaped(tmp_path, good, gcc, which):
    """Defence in depth: facts that bypass every validation still give inert files:
    ``statement``, two statement lines (one ends the C comment and defines a function, one
    ends the docstring and writes a file: unescaped, both work); ``everything``, the name,
    status and sha256 strings and every statement line hostile (the C string literals read
    back as the exact bytes)."""
    trap = tmp_path / "trap"
    trap.mkdir()
    evil = payloads(trap)
    cdir = load_controller_dir(good)
    bank = export_bank(cdir)
    if which == "statement":
        guarded = f"*/\n#ifndef {MARK}_G\n#define {MARK}_G\n{evil[3][3:-3]}\n#endif\n/*"
        fx = dataclasses.replace(facts(cdir), statement=(guarded, evil[0]))
        assert_inert_c(c_files(bank, fx, "qsls_ctrl", "double"), tmp_path / "c", gcc, 2)
        assert_inert_py(module(bank, fx), trap)
        return
    everything = " ".join(evil)
    fx = dataclasses.replace(
        facts(cdir), name=everything, status=evil[4], sha256=evil[5] + evil[1],
        statement=tuple(evil),
    )  # fmt: skip
    files = c_files(bank, fx, "qsls_ctrl", "double")
    assert_inert_c(files, tmp_path / "c", gcc, len(evil))
    main = tmp_path / "c" / "main.c"
    main.write_text(
        '#include <stdio.h>\n#include "qsls_ctrl.h"\nint main(void) { fputs(QSLS_CTRL_STATUS, '
        "stdout); putchar(0); fputs(QSLS_CTRL_SHA256, stdout); return 0; }\n"
    )
    exe = tmp_path / "c" / "main"
    res = subprocess.run([gcc, *STRICT, "-o", str(exe), str(main)], capture_output=True)
    assert res.returncode == 0, res.stderr
    out = subprocess.run([str(exe)], capture_output=True, check=True).stdout
    assert out.split(b"\0") == [evil[4].encode(), (evil[5] + evil[1]).encode()]
    mod = assert_inert_py(module(bank, fx), trap)
    assert [getattr(mod, k) for k in ("NAME", "STATUS")] == [everything, evil[4]]
