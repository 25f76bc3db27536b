"""
The commands' outputs stay bit-identical: SHA-256 of every file they write, against the stored.

`golden_outputs` runs ``simulate``, ``diagnose``, ``fit`` and ``evaluate`` on a
simulated record, and ``diagnose`` and ``fit`` on the measured thermal
cycle, through the CLI's code path in a scratch folder; the digests of
``params.yaml``, ``report.json``, the fit's parameter file and ``evaluate
--json``'s output are held against ``test/support/golden/outputs.json``. The commands
use relative paths, and the outputs hold no timing, version or absolute path:
nothing is normalised before hashing. The digests are regenerated on purpose
when an issue changes behaviour (``.venv/bin/python test/support/golden_outputs.py
--write``, committed with the change); a failure names each output that
changed, where this run's files are, and how to diff them against the
stored commit's (golden_outputs.py's docstring).
"""

import golden_outputs
import pytest


@pytest.mark.parametrize('case', golden_outputs.CASES, ids=lambda case: case.name)
def test_outputs_match_the_stored_digests(case, tmp_path):
    if case.missing():
        pytest.skip(f'{case.name}: input not on this machine: {", ".join(case.missing())}')
    digests = golden_outputs.run_case(case, tmp_path / case.name)
    found = golden_outputs.changes(case, golden_outputs.load(), digests)
    assert not found, golden_outputs.mismatch_message(found, tmp_path / case.name)


def test_the_digests_tell_outputs_apart(tmp_path):
    """A digest is of the bytes: one byte more in an output gives another digest."""
    path = tmp_path / 'params.yaml'
    path.write_bytes(b'a: 1.0\n')
    before = golden_outputs.digest(path)
    path.write_bytes(b'a: 1.00\n')
    assert golden_outputs.digest(path) != before
    stored = {'simulated': {'commands': golden_outputs.SIMULATED.lines(),
                            'outputs': {'params.yaml': before}}}
    found = golden_outputs.changes(golden_outputs.SIMULATED, stored,
                                   {'params.yaml': golden_outputs.digest(path)})
    assert found == [f'simulated/params.yaml: stored {before}, now '
                     f'{golden_outputs.digest(path)}']
