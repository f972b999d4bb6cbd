"""Hostile inputs across the commands and file formats: every one is refused in one line that
starts with the command's name (exit 1 or 2), or gives a correct result; none ends in a
traceback or leaves partial output behind.

Each case is (command line, files it needs). ``{d}`` in an argument is a fresh directory;
``{name}`` names a file of ``FILES`` written into it first. The commands run in this process
(what a user runs is ``dmf-sim ARGS``), with their computations allowed: a case the checks let
through would compute and then fail the exit-code check.
"""
from __future__ import annotations

from pathlib import Path

import pytest
from support.dds_peer import new_domain

from dmf_sim.cli import main as cli_main

LONG = 'x' * 300
ROOT = Path(__file__).resolve().parents[2]
TRUCK = str(ROOT / 'config' / 'truck_dmf.yaml')

# Files the cases read: name -> content.
FILES = {
    'inertia.yaml': Path(TRUCK).read_text().replace('inertia: 0.1837', 'inertia: 1.0e308'),
    'stiffness.yaml': Path(TRUCK).read_text().replace('stiffness: 142835', 'stiffness: 1e300'),
    'damping.yaml': Path(TRUCK).read_text().replace('damping: 49.5', 'damping: 1e300'),
    'dupkeys.yaml': Path(TRUCK).read_text() + 'name: again\n',
    'notyaml.yaml': 'base: truck_dmf\n  elements: [\n',
    'list.yaml': '- 1\n- 2\n',
    'empty.yaml': '',
    'jump.csv': 'time_s,speed_rpm,load\n0,800,1\n0.00001,2000,1\n1,2000,1\n',
    'long.csv': 'time_s,speed_rpm,load\n0,800,1\n1e9,800,1\n',
    'negload.csv': 'time_s,speed_rpm,load\n0,800,1\n1,800,7\n',
    'backwards.csv': 'time_s,speed_rpm,load\n0,800,1\n2,900,1\n1,900,1\n',
    'nan.csv': 'time_s,speed_rpm,load\n0,nan,1\n1,800,1\n',
    'header.csv': 'a,b\n1,2\n',
    'text.mcap': 'not an mcap file at all, just some text here',
    'short.mcap': 'hello\n',
    'faults_bad.yaml': 'faults:\n  - {kind: misfire, cylinders: [9], at_s: 1}\n',
    'faults_kind.yaml': 'faults:\n  - {kind: explode, at_s: 1}\n',
    'faults_time.yaml': 'faults:\n  - {kind: misfire, cylinders: [1], start_s: 5, end_s: 2}\n',
    'study_empty.yaml': 'parameters: {}\n',
}
BINARY = {'binary.yaml': b'\x00\x01\x02\xff', 'tiny.mcap': b'\x89MCAP0\r\n'}

CASES = [
    # numbers out of range or not numbers
    ['run', 'ramp:800:1000:100', '--rate', '1e-3', '--no-write'],
    ['run', 'ramp:800:1000:100', '--rate', 'nan', '--no-write'],
    ['run', 'ramp:800:1000:-5', '--no-write'],
    ['run', 'ramp:800:1000:100:0:0', '--no-write', '--threads', '0'],
    ['run', 'ramp:800:1000:1e30', '--no-write'],
    ['run', 'ramp:100000:100001:10', '--no-write'],
    ['run', 'ramp:800:1000', '--no-write'],
    ['run', 'ramp:a:b:c', '--no-write'],
    ['run', 'no_such_profile', '--no-write'],
    ['run', '{d}/jump.csv', '--no-write'],
    ['run', '{d}/long.csv', '--no-write'],
    ['run', '{d}/negload.csv', '--no-write'],
    ['run', '{d}/backwards.csv', '--no-write'],
    ['run', '{d}/nan.csv', '--no-write'],
    ['run', '{d}/header.csv', '--no-write'],
    ['run', 'ramp:800:1000:100', '--no-write', '--config', ''],
    ['run', 'ramp:800:1000:100', '--no-write', '--config', '{d}/inertia.yaml'],
    ['run', 'ramp:800:1000:100', '--no-write', '--config', '{d}/dupkeys.yaml'],
    ['run', 'ramp:800:1000:100', '--no-write', '--config', '{d}/notyaml.yaml'],
    ['run', 'ramp:800:1000:100', '--no-write', '--config', '{d}/list.yaml'],
    ['run', 'ramp:800:1000:100', '--no-write', '--config', '{d}/empty.yaml'],
    ['run', 'ramp:800:1000:100', '--no-write', '--config', '{d}/binary.yaml'],
    ['run', 'ramp:800:1000:100', '--no-write', '--config', '{d}/missing.yaml'],
    ['run', 'ramp:800:1000:100', '--no-write', '--engine', '{d}/dupkeys.yaml'],
    ['run', 'ramp:800:1000:100', '--no-write', '--faults', '{d}/faults_bad.yaml'],
    ['run', 'ramp:800:1000:100', '--no-write', '--faults', '{d}/faults_kind.yaml'],
    ['run', 'ramp:800:1000:100', '--no-write', '--faults', '{d}/faults_time.yaml'],
    ['run', 'ramp:800:1000:100', '--out', '{d}/' + LONG],
    ['run', 'ramp:800:1000:100', '--out', TRUCK],
    ['run', 'ramp:800:1000:100', '--no-write', '--namespace', 'bad//ns'],
    ['run', 'ramp:800:1000:100', '--no-write', '--namespace', '9truck'],
    ['run', 'ramp:800:1000:100', '--no-write', '--namespace', 'a b'],
    ['steady', '--speed', '-1000'],
    ['steady', '--speed', 'inf'],
    ['steady', '--speed', '1000', '--load', '2'],
    ['steady', '--speed', '1000', '--config', '{d}/inertia.yaml'],
    ['sweep', '--no-progress', '--speeds', '2000', '800', '10'],
    ['sweep', '--no-progress', '--speeds', '800', '2000', '0'],
    ['sweep', '--no-progress', '--harmonics', '100000'],
    ['sweep', '--no-progress', '--theta', '5'],
    ['sweep', '--no-progress', '--config', '{d}/damping.yaml'],
    ['modes', '--config', '{d}/stiffness.yaml'],
    ['sweep', '--no-progress', '--out', TRUCK],
    ['sweep', '--no-progress', '--out', '{d}/' + LONG],
    ['modes', '--config', '{d}/' + LONG + '.yaml'],
    ['modes', '--config', '{d}/binary.yaml'],
    ['loads', '--torque-speeds', '800', '-5'],
    ['runup', 'up', 'down', 'up'],
    ['runup', '{d}/tiny.mcap'],
    ['analyze', '{d}/tiny.mcap'],
    ['analyze', '{d}/text.mcap'],
    ['analyze', '{d}/missing_bag'],
    ['analyze', '{d}/' + LONG],
    ['durability', '{d}/tiny.mcap'],
    ['durability', '{d}/text.mcap'],
    ['durability', '{d}/short.mcap'],
    ['analyze', '{d}/short.mcap'],
    ['identify', '{d}/short.mcap'],
    ['bag-recover', '{d}/tiny.mcap', '-o', '{d}/fixed.mcap'],
    ['bag-recover', '{d}/text.mcap', '-o', '{d}/fixed.mcap'],
    ['design', '{d}/study_empty.yaml', '--out', '{d}/study'],
    ['design', '{d}/missing.yaml', '--out', '{d}/study'],
    ['design', 'config/study_example.yaml', '--workers', '100000', '--out', '{d}/study'],
    ['identify', '{d}/tiny.mcap'],
    ['identify', '{d}/text.mcap', '--seed', '-1'],
    ['optimize', 'config/optimize_example.yaml', '--budget', '-3', '--out', '{d}/opt'],
    ['optimize', 'config/optimize_example.yaml', '--budget', '1e12', '--out', '{d}/opt'],
    ['nnm', '--out', TRUCK],
    ['setpoint', '--timeout', '1e12', '--speed', '1000'],
    ['setpoint', '--profile', 'ramp:300:1400:-50'],
    ['setpoint', '--speed', '1000', '--namespace', '9truck'],
    ['monitor', '--namespace', 'bad//ns'],
    ['fault', '{kind: misfire, cylinders: [0]}'],
    ['fault', '{kind: explode}'],
    ['fault', '{kind: dmf_stiffness, stage: 1, factor: -2}'],
    ['fault', '{kind: [unclosed'],
]


@pytest.mark.slow
@pytest.mark.parametrize('argv', CASES, ids=[' '.join(c)[:60] for c in CASES])
def test_hostile_input_gets_one_line(argv, tmp_path, capsys, monkeypatch):
    # a command that got as far as DDS stays on this machine, in a domain of the tests' range
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_DOMAIN_ID', str(new_domain()))
    monkeypatch.chdir(ROOT)
    for name, text in FILES.items():
        (tmp_path / name).write_text(text, encoding='utf-8')
    for name, data in BINARY.items():
        (tmp_path / name).write_bytes(data)
    args = [a.replace('{d}', str(tmp_path)) for a in argv]
    try:
        code = cli_main(args)
    except SystemExit as stop:          # argparse refuses a malformed command line this way
        code = stop.code
    err = capsys.readouterr().err
    assert 'Traceback' not in err, err
    assert code in (1, 2), (code, err)
    lines = [ln for ln in err.splitlines() if ln.startswith('dmf-sim')]
    assert len(lines) == 1 and lines[0].startswith(f'dmf-sim {argv[0]}: error: '), err
    assert not (tmp_path / 'study').exists() and not (tmp_path / 'opt').exists()
