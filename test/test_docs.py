"""The user documentation holds together: every relative link in README.md, CHANGELOG.md and doc/*.md points to an
existing file (and heading, for a #anchor), and the README's test command is the one .ci/run runs."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
_FENCE = re.compile(r'^(```|~~~).*?^\1', re.M | re.S)
_CODE = re.compile(r'`[^`\n]*`')
_LINK = re.compile(r'!?\[[^\]\n]*\]\(([^)\s]+)(?:\s+"[^"]*")?\)')
_HEADING = re.compile(r'^#{1,6}\s+(.*?)\s*#*\s*$', re.M)


def documents() -> list[Path]:
    """The files users read: README.md, CHANGELOG.md and the top level of doc/ (drafts and history excluded)."""
    return [ROOT / 'README.md', ROOT / 'CHANGELOG.md', *sorted((ROOT / 'doc').glob('*.md'))]


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, code marks and punctuation dropped, spaces to hyphens."""
    text = heading.strip().lower().replace('`', '')
    text = re.sub(r'[^\w\- ]', '', text)
    return text.replace(' ', '-')


def anchors(text: str) -> set[str]:
    """Every heading's anchor in a Markdown text (repeated headings get -1, -2, ... as on GitHub)."""
    seen: dict[str, int] = {}
    out = set()
    for heading in _HEADING.findall(_FENCE.sub('', text)):
        base = slug(heading)
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f'{base}-{n}')
    return out


def broken_links(path: Path) -> list[str]:
    """Relative links in one Markdown file whose target file or #anchor does not exist."""
    text = path.read_text(encoding='utf-8')
    prose = _CODE.sub('', _FENCE.sub('', text))
    bad = []
    for target in _LINK.findall(prose):
        if re.match(r'^[a-z][a-z0-9+.-]*:', target):  # http:, https:, mailto:: not ours to check offline
            continue
        file_part, _, anchor = target.partition('#')
        dest = (path.parent / file_part).resolve() if file_part else path
        if not dest.exists():
            bad.append(f'{target} (no file {dest})')
        elif anchor and dest.suffix == '.md' and anchor not in anchors(dest.read_text(encoding='utf-8')):
            bad.append(f'{target} (no heading #{anchor} in {dest.name})')
    return bad


def test_every_relative_link_resolves():
    problems = {p.relative_to(ROOT).as_posix(): broken_links(p) for p in documents() if p.exists()}
    assert {k: v for k, v in problems.items() if v} == {}
    assert (ROOT / 'CHANGELOG.md').exists()


def test_every_document_opens_with_its_title():
    firsts = {p.name: p.read_text(encoding='utf-8').split('\n', 1)[0] for p in documents() if p.exists()}
    assert {name: line for name, line in firsts.items() if not line.startswith('# ')} == {}


def test_the_checker_sees_a_broken_file_and_a_broken_anchor(tmp_path):
    (tmp_path / 'a.md').write_text('# Top `x` (y)\n\n## Top `x` (y)\n', encoding='utf-8')
    doc = tmp_path / 'b.md'
    doc.write_text('[ok](a.md#top-x-y-1) [file](missing.md) [anchor](a.md#nowhere) `[code](skipped.md)`\n'
                   '```\n[fenced](skipped.md)\n```\n[web](https://example.org)\n', encoding='utf-8')
    bad = broken_links(doc)
    assert len(bad) == 2 and bad[0].startswith('missing.md') and bad[1].startswith('a.md#nowhere')


def test_readme_test_command_is_what_ci_runs():
    """.ci/run runs exactly the README's second command (the test suite)."""
    readme = (ROOT / 'README.md').read_text(encoding='utf-8')
    ci = (ROOT / '.ci' / 'run').read_text(encoding='utf-8')
    commands = [line.strip() for line in readme.splitlines() if line.startswith('python3 -m venv .venv && ')]
    assert len(commands) == 2, commands
    setup_and_test = commands[1]
    assert setup_and_test.endswith('-m pytest -q') and setup_and_test in ci


def test_readme_keeps_the_generated_parameter_table_markers():
    readme = (ROOT / 'README.md').read_text(encoding='utf-8')
    begin, end = readme.find('<!-- parameters:begin'), readme.find('<!-- parameters:end -->')
    assert 0 < begin < end and '`tau_acc_s`' in readme[begin:end] and '|---|' in readme[begin:end]


def test_the_issue_s_benchmark_path_runs_the_simulated_accuracy_script():
    """`benchmarks/simulated_accuracy.py` (issue 23's name) runs `experiments/simulated_accuracy.py` with the same
    arguments, from any working directory."""
    import subprocess
    import sys

    def out(script: str) -> str:
        r = subprocess.run([sys.executable, str(ROOT / script), '--help'], cwd=ROOT.parent, capture_output=True,
                           text=True, timeout=60, check=True)
        return r.stdout

    text = out('experiments/simulated_accuracy.py')
    assert 'magnetic environments' in text
    assert out('benchmarks/simulated_accuracy.py') == text
