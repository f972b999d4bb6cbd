"""The documentation stays where a clone can read it.

The site itself is built by `make docs` (run by `make test`) with warnings as errors; these checks
are the cheap ones that need no Sphinx: nothing in the repository cites notes outside it, the
README stays short and its links resolve, and every `dmf-sim` command has its page.
"""
import importlib
import pkgutil
import re
from pathlib import Path

import pytest

from dmf_sim import commands

ROOT = Path(__file__).resolve().parents[1]
# Generated or installed trees, not the repository's own files.
SKIP_DIRS = {'.git', '.venv', 'build', 'install', 'log', '_build', '__pycache__',
             '.pytest_cache', 'out'}
TEXT_SUFFIXES = {'.py', '.md', '.yaml', '.yml', '.xml', '.cfg', '.toml', '.json', '.csv', '.txt',
                 ''}
README_MAX_BYTES = 12 * 1024          # README <= ~12 KB, the rest lives in doc/
# A citation of the design notes or of anything beside the repository (the notes folder beside a
# checkout). The page doc/commands/design-study.md is named so that it never matches.
OUTSIDE = re.compile(r'(?<![\w-])design\.md|\.\./shared\b|/shared/(design|engine-notes)')
LINK = re.compile(r'\]\(([^)#\s]+)(?:#[^)]*)?\)')


def _repository_files():
    for path in ROOT.rglob('*'):
        rel = path.relative_to(ROOT)
        if any(part in SKIP_DIRS or part.endswith('.egg-info') or part.startswith('.venv')
               for part in rel.parts):                       # .venv-jazzy, .venv-noros too
            continue
        if path.is_file() and path.suffix in TEXT_SUFFIXES:
            yield rel, path


@pytest.mark.slow
def test_nothing_cites_notes_outside_the_repository():
    hits = []
    for rel, path in _repository_files():
        if rel == Path('test/test_docs.py'):
            continue                        # this file names the pattern it looks for
        for n, line in enumerate(path.read_text(errors='replace').splitlines(), 1):
            if OUTSIDE.search(line):
                hits.append(f'{rel}:{n}: {line.strip()}')
    assert not hits, 'cite doc/theory.md, doc/architecture.md, doc/engine.md instead:\n' + \
        '\n'.join(hits)


def test_readme_is_short_and_its_links_resolve():
    readme = ROOT / 'README.md'
    assert readme.stat().st_size <= README_MAX_BYTES, readme.stat().st_size
    text = readme.read_text()
    targets = [t for t in LINK.findall(text) if '://' not in t]
    assert targets, 'the README links into doc/'
    missing = [t for t in targets if not (ROOT / t).exists()]
    assert not missing, missing


def test_every_command_has_its_page_in_the_table():
    names = [importlib.import_module(f'{commands.__name__}.{info.name}').NAME
             for info in pkgutil.iter_modules(commands.__path__) if not info.name.startswith('_')]
    assert len(names) >= 11
    table = (ROOT / 'doc' / 'commands' / 'index.md').read_text()
    readme = (ROOT / 'README.md').read_text()
    for name in names:
        row = re.search(rf'\[`{re.escape(name)}`\]\(([^)]+)\)', table)
        assert row, f'dmf-sim {name} is missing from doc/commands/index.md'
        assert (ROOT / 'doc' / 'commands' / row.group(1)).exists(), row.group(1)
        assert f'[`{name}`](doc/commands/' in readme, f'dmf-sim {name} is missing from the README'


def _python_blocks(path: Path) -> list[str]:
    return re.findall(r'```python\n(.*?)```', path.read_text(), re.S)


@pytest.mark.parametrize('page', ['README.md', 'doc/guide/python-api.md'])
def test_the_api_examples_run(page, capsys):
    """The README's API example and the guide's first script run as printed (a short
    example in the README, a runnable one in the docs), through `import dmf_sim as dmf` only."""
    code = _python_blocks(ROOT / page)[0]
    assert code.startswith('import dmf_sim as dmf\n')
    exec(compile(code, page, 'exec'), {'__name__': '__docs_example__'})
    out = capsys.readouterr().out
    assert 'steady after' in out          # Newmark reached its steady state
    assert re.search(r'^True |: stable,', out, re.M)   # the harmonic balance: a stable state


# ---- command pages whose commands run as printed -----------------------------------------------
def _shell_lines(page: str) -> list[list[str]]:
    """The commands of a page's ```bash blocks, in order, as argv (comments dropped)."""
    import shlex
    text = (ROOT / page).read_text()
    lines = [line for block in re.findall(r'```bash\n(.*?)```', text, re.S)
             for line in block.splitlines()]
    return [argv for argv in (shlex.split(line, comments=True) for line in lines) if argv]


def _run(argv: list[str]) -> int:
    """One command of a page: dmf-sim in this process, python3 as this interpreter."""
    import subprocess
    import sys

    from dmf_sim.cli import main as cli_main
    if argv[0] == 'dmf-sim':
        return cli_main(argv[1:])
    assert argv[0] == 'python3', argv
    return subprocess.run([sys.executable, *argv[1:]], timeout=120).returncode


@pytest.mark.slow
def test_the_runup_page_runs_as_printed(tmp_path, monkeypatch, capsys):
    """The page used case.yaml / case.csv that no page showed how to make. Its commands now run
    in order in an empty directory, and the fold case jumps where the page says."""
    monkeypatch.chdir(tmp_path)
    commands = _shell_lines('doc/commands/runup.md')
    assert [a[:2] for a in commands if a[0] == 'dmf-sim'].count(['dmf-sim', 'runup']) == 2
    for argv in commands:
        if argv[:2] == ['dmf-sim', 'run']:
            argv = [*argv, '--no-progress']
        assert _run(argv) == 0, argv
    for out in ('paper_runup', 'hysteresis'):
        assert (tmp_path / out / 'runup.png').stat().st_size > 10_000
    printed = capsys.readouterr().out
    page = (ROOT / 'doc' / 'commands' / 'runup.md').read_text()
    shown = re.search(r'```text\n(.*?)```', page, re.S).group(1).splitlines()
    for line in shown:
        assert line in printed.splitlines(), line


def test_the_bag_recover_page_runs_as_printed(tmp_path, monkeypatch, capsys):
    """The page's `-o fixed.mcap` was refused for a split bag: its commands now run in order on
    a crashed split bag, and the refusal it describes is one line naming -o."""
    from dmf_sim.transient.profiles import read_profile
    from dmf_sim.transient.run import RunOptions, run_profile
    monkeypatch.chdir(tmp_path)
    run_profile(read_profile('ramp:1000:1200:100:1.0:0.5'), tmp_path / 'run1',
                RunOptions(split_s=1.0))
    files = sorted((tmp_path / 'run1').glob('*.mcap'))
    assert len(files) >= 3                                      # a split bag ...
    with files[-1].open('r+b') as fh:                           # ... its last file cut short
        fh.truncate(files[-1].stat().st_size // 2)
    for argv in _shell_lines('doc/commands/bag-recover.md'):
        assert _run(argv) == 0, argv
    assert (tmp_path / 'fixed.mcap').is_file() and (tmp_path / 'fixed').is_dir()
    capsys.readouterr()
    assert _run(['dmf-sim', 'bag-recover', 'run1', '-o', 'whole.mcap']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'whole.mcap: a bare .mcap file holds one file' in err, err


@pytest.mark.slow
def test_the_virtual_truck_page_offline_run_records_its_misfire(tmp_path, monkeypatch, capsys):
    """The page's offline run, as printed (its --out moved to a scratch directory): the bag
    holds the sensor topics and, in the ground truth, the single misfire of cylinder 3 the
    schedule puts at 2 s."""
    from dmf_sim.bags.read import read_messages
    from dmf_sim.live.streams import resolved_topics
    from dmf_sim.physics.faults import event_from_values
    monkeypatch.chdir(ROOT)
    runs = [a for a in _shell_lines('doc/guide/virtual-truck.md')
            if a[0].endswith('dmf-sim') and a[1] == 'run']
    assert len(runs) == 1
    argv = runs[0][1:]
    argv[argv.index('--out') + 1] = str(tmp_path / 'faults_run')
    from dmf_sim.cli import main as cli_main
    assert cli_main([*argv, '--no-progress']) == 0
    capsys.readouterr()
    topics = resolved_topics()
    misfires, counts = [], {}
    for m in read_messages(tmp_path / 'faults_run'):
        counts[m.topic] = counts.get(m.topic, 0) + 1
        if m.topic == topics['fault_ground_truth']:
            s = m.msg.status[0]
            event = event_from_values(s.message, {kv.key: kv.value for kv in s.values})
            if s.message.startswith('misfire:'):
                misfires.append(event)
    assert counts['/sensors/crank/edges'] > 0 and counts['/vehicle_bus/engine_speed'] > 0
    first = misfires[0]
    assert first['cylinder'] == 3 and 2.0 <= first['event_s'] < 2.2, first
