"""A key given twice in one YAML mapping is refused with file:line:column naming the key, in
every YAML file the package reads (PyYAML alone keeps the last value silently)."""
from __future__ import annotations

import pytest

from dmf_sim.cli import main as cli_main
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.paths import config_dir, parse_yaml


def _with_duplicate(text: str, line_start: str, key: str, value: str) -> tuple[str, int]:
    """``text`` with ``key: value`` added again right after the first line starting with
    ``line_start`` (same indentation); returns the text and the 1-based line of the copy."""
    lines = text.splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith(line_start))
    indent = len(lines[i]) - len(lines[i].lstrip())
    lines.insert(i + 1, ' ' * indent + f'{key}: {value}')
    return '\n'.join(lines) + '\n', i + 2


def test_parse_yaml_names_the_key_and_where():
    with pytest.raises(ConfigError) as e:
        parse_yaml('a: 1\nb:\n  c: 2\n  c: 3\n', 'f.yaml')
    assert str(e.value) == "f.yaml:4:3: invalid YAML: duplicate key 'c' (first given on line 3)"
    with pytest.raises(ConfigError, match=r"f.yaml:1:10: .*duplicate key 'n'"):
        parse_yaml('- {n: 1, n: 2}\n', 'f.yaml')


def test_merge_keys_may_still_be_overridden():
    assert parse_yaml('b: &x {c: 1, d: 2}\ne:\n  <<: *x\n  c: 5\n', 'f') == {
        'b': {'c': 1, 'd': 2}, 'e': {'c': 5, 'd': 2}}


@pytest.mark.parametrize('name, start, key, value, load', [
    ('truck_dmf', 'name:', 'name', 'other', 'driveline'),
    ('engine_d13', 'name:', 'name', 'other', 'engine'),
    ('study_example', 'engine:', 'engine', 'engine_d13', 'study'),
    ('optimize_example', 'engine:', 'engine', 'engine_d13', 'problem'),
    ('durability', '  exponent:', 'exponent', '9.0', 'durability'),
    ('profiles/truck_road_cycle', 'name:', 'name', 'other', 'profile'),
])
def test_every_file_format_refuses_a_duplicate_key(name, start, key, value, load, tmp_path):
    from dmf_sim.design.study import read_study
    from dmf_sim.durability.settings import read_settings
    from dmf_sim.optimize.problem import read_problem
    from dmf_sim.physics.engine.config import read_engine_config
    from dmf_sim.physics.model import read_driveline
    from dmf_sim.transient.profiles import read_profile
    loaders = {'driveline': read_driveline, 'engine': read_engine_config, 'study': read_study,
               'problem': read_problem, 'durability': read_settings, 'profile': read_profile}
    text, line = _with_duplicate((config_dir() / (name + '.yaml')).read_text(), start, key,
                                 value)
    path = tmp_path / (name.split('/')[-1] + '.yaml')
    path.write_text(text)
    with pytest.raises(ConfigError) as e:
        loaders[load](str(path))
    msg = str(e.value)
    assert f'{path}:{line}:' in msg and f"duplicate key '{key}'" in msg, msg
    assert '\n' not in msg


def test_the_cli_refuses_a_duplicate_inertia_in_one_line(tmp_path, capsys):
    text = (config_dir() / 'truck_dmf.yaml').read_text().replace(
        'inertia: 0.1065}', 'inertia: 0.1065, inertia: 1e308}', 1)
    path = tmp_path / 'dup.yaml'
    path.write_text(text)
    assert cli_main(['modes', '--config', str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and f'{path}:' in err and "duplicate key 'inertia'" in err, err
