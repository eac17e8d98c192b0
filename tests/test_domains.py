"""The tests' DDS domain leases (domains.py): exclusive across processes, freed when the holder dies.

The lease tests use a lock directory of their own, so that other runs of the suite on this machine
(which hold leases in the shared one) cannot change what they see.
"""

import os
import subprocess
import sys
from pathlib import Path

import domains
import pytest

HOLDER = """
import sys, time
from pathlib import Path
sys.path.insert(0, sys.argv[1])
import domains
domains.LOCK_DIR = Path(sys.argv[2])
held = [domains.lease() for _ in range(int(sys.argv[3]))]
print(" ".join(str(h.id) for h in held), flush=True)
time.sleep(300)
"""


@pytest.fixture
def lock_dir(tmp_path, monkeypatch):
    monkeypatch.setattr(domains, "LOCK_DIR", tmp_path)
    monkeypatch.setattr(domains, "_USER_DOMAIN", "0")
    return tmp_path


def _holder(lock_dir: Path, n: int) -> tuple[subprocess.Popen, set[int]]:
    p = subprocess.Popen([sys.executable, "-c", HOLDER, str(Path(domains.__file__).parent), str(lock_dir), str(n)],
                         stdout=subprocess.PIPE, text=True)
    assert p.stdout is not None
    return p, {int(x) for x in p.stdout.readline().split()}


def test_the_run_has_its_own_domain_and_no_foreign_dds_config():
    assert 1 <= int(os.environ["ROS_DOMAIN_ID"]) <= 101
    assert os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert not any(name in os.environ for name in domains.FOREIGN_DDS_ENV)


def test_ids_held_by_another_process_are_leased_only_after_it_dies(lock_dir):
    p, theirs = _holder(lock_dir, 60)
    try:
        assert len(theirs) == 60
        mine = [domains.lease() for _ in range(len(domains.DOMAIN_IDS) - 60)]  # every id left
        assert not {m.id for m in mine} & theirs
        with pytest.raises(RuntimeError, match=r"all DDS domain ids 1\.\.101 are held"):
            domains.lease()
    finally:
        p.kill()
        p.wait()
    # the kernel dropped the dead holder's locks: exactly its ids can be leased again
    again = [domains.lease() for _ in range(60)]
    assert {a.id for a in again} == theirs
    for m in mine + again:
        m.release()


def test_successive_leases_in_one_process_do_not_reuse_the_last_id(lock_dir):
    with domains.lease() as a:
        pass
    with domains.lease() as b:
        pass
    assert a != b


def test_the_users_domain_is_never_leased(lock_dir, monkeypatch):
    monkeypatch.setattr(domains, "_USER_DOMAIN", "7")
    leases = [domains.lease() for _ in range(len(domains.DOMAIN_IDS) - 1)]
    assert 7 not in {d.id for d in leases}
    for d in leases:
        d.release()
