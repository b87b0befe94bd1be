"""Issue 50's last input-handling items: the warnings a user needs (an evaluated flight that
is a training flight's twin; ingest streams that look swapped; an implausible ingest error),
the calibration's refusal naming the premise quantity it found broken, the certificate
reader's alias refusal naming its file, and refusals that lead with what to do."""

from __future__ import annotations

import pytest

from qsls.pipeline.core.errors import InputError


def _bomb(levels: int = 9) -> list[str]:
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{k}: &a{k} [{', '.join([f'*a{k - 1}'] * 9)}]" for k in range(1, levels + 1)]
    return lines


def test_a_certificate_alias_bomb_refusal_names_the_file(tmp_path):
    from qsls.pipeline.control.artifacts import Certificate

    cert = tmp_path / "ctrl" / "certificate.yaml"
    cert.parent.mkdir()
    cert.write_text("controller: l1\n" + "".join(f"{ln}\n" for ln in _bomb()) + "b: *a9\n")
    with pytest.raises(InputError, match="expands to more than") as exc:
        Certificate.load(cert.parent)
    assert str(exc.value).startswith(f"{cert}:")
