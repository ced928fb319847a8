"""The remote compare-and-swap (`Backend.swap`) called directly, on both remote kinds (issue 23).

The push tests only reach the compare through a thread race; here each case is one deterministic call
with a stale or wrong expected version, and the key's bytes are checked afterwards. Planted bugs named:
    cas-no-compare        swap writes without comparing the expected version (directory and S3)
    cas-create-overwrites expect=None (create) on a key that exists replaces it
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from remote_support import moto_endpoint, remote_url, s3_env  # noqa: E402,F401

from artifacts.remotes.backends import RefMoved  # noqa: E402
from artifacts.remotes.config import parse_url  # noqa: E402
from artifacts.remotes.connect import open_backend  # noqa: E402

KEY = "refs/team/handoff"


@pytest.fixture
def backend(remote_url):
    b = open_backend(parse_url("origin", remote_url))
    b.probe(create=True)
    return b


def stored(backend) -> bytes | None:
    got = backend.read_versioned(KEY)
    return None if got is None else got[0]


def test_create_then_swap_with_the_current_version_moves_the_key(backend):
    v1 = backend.swap(KEY, b"one\n", None)
    assert backend.read_versioned(KEY) == (b"one\n", v1)
    v2 = backend.swap(KEY, b"two\n", v1)
    assert v2 != v1
    assert backend.read_versioned(KEY) == (b"two\n", v2)


def test_swap_with_a_stale_expected_version_is_refused_and_changes_nothing_cas_no_compare(backend):
    """Mutation cas-no-compare: a writer that read v1 may not replace v2."""
    v1 = backend.swap(KEY, b"one\n", None)
    v2 = backend.swap(KEY, b"two\n", v1)
    with pytest.raises(RefMoved):
        backend.swap(KEY, b"stale\n", v1)
    assert backend.read_versioned(KEY) == (b"two\n", v2)


def test_swap_expecting_a_version_of_a_missing_key_is_refused_cas_no_compare(backend):
    """The key was deleted (or never written) since the writer read it."""
    other = backend.swap("refs/team/other", b"x\n", None)
    with pytest.raises(RefMoved):
        backend.swap(KEY, b"ghost\n", other)
    assert stored(backend) is None


def test_create_on_an_existing_key_is_refused_cas_create_overwrites(backend):
    """Mutation cas-create-overwrites: expect=None means "absent"; two first pushes cannot both win."""
    v1 = backend.swap(KEY, b"first\n", None)
    with pytest.raises(RefMoved):
        backend.swap(KEY, b"second\n", None)
    assert backend.read_versioned(KEY) == (b"first\n", v1)


def test_a_refused_swap_leaves_no_lock_behind(backend):
    """After a refused swap the next writer with the right version succeeds at once."""
    v1 = backend.swap(KEY, b"one\n", None)
    with pytest.raises(RefMoved):
        backend.swap(KEY, b"stale\n", "not-a-version")
    v2 = backend.swap(KEY, b"two\n", v1)
    assert backend.read_versioned(KEY) == (b"two\n", v2)
