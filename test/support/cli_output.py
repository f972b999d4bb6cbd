"""What a command printed: its one error line, the monitor's frames (helpers)."""
from __future__ import annotations

import re


def one_line_error(capsys) -> str:
    """The one line a refused command wrote to stderr (asserts there is exactly one)."""
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def frames(text: str) -> list[dict[str, str]]:
    """--plain output -> one dict per frame: label -> text."""
    out = []
    for block in re.split(r'^--- frame \d+ t=[\d.]+ s$', text, flags=re.M)[1:]:
        rows = {}
        for line in block.strip().splitlines():
            label, _, rest = line.partition(' ')
            rows[label] = rest.strip()
        out.append(rows)
    return out
