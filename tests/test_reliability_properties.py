"""Property-based tests (Hypothesis) for the two parsers users feed directly: the store's id/ref
parsing (whatever is typed or found on disk resolves or gives one short StoreError) and workflow
validation (any YAML-shaped value parses or gives one short StageError naming a field; numbers
refuse true/false, inf and nan)."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from artifacts.errors import StoreError
from artifacts.hashing import hash_bytes, is_full_id
from artifacts.refs import _read_ref_file, check_ref_name, read_ref, set_ref
from artifacts.resolve import resolve
from artifacts.store import Store
from stages.errors import StageError
from stages.workflow import parse_workflow

FAST = settings(max_examples=150, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
SEGMENT = st.from_regex(r"\A[A-Za-z0-9][A-Za-z0-9._+-]{0,20}\Z")
REF_NAMES = st.lists(SEGMENT, min_size=1, max_size=4).map("/".join)


def one_short_line(exc: BaseException) -> None:
    text = str(exc)
    assert "\n" not in text and 0 < len(text) < 700, text[:300]


@pytest.fixture(scope="module")
def store() -> Store:
    with tempfile.TemporaryDirectory() as tmp:
        st_ = Store.init(Path(tmp) / "store")[0]
        st_.put_json({"type": "tree", "format": 1, "entries": []})
        yield st_
        st_.close()


# ----------------------------------------------------------------------------- store ids and refs
@FAST
@given(st.binary(max_size=2000))
def test_content_ids_are_full_hex_ids(data):
    oid = hash_bytes(data)
    assert is_full_id(oid) and len(oid) == 64


@FAST
@given(st.text(max_size=300))
def test_ref_names_are_valid_or_refused_in_one_short_line(name):
    try:
        assert check_ref_name(name) == name
    except StoreError as exc:
        one_short_line(exc)
        return
    assert all(
        part and part not in (".", "..") and "/" not in part and not part.startswith(".") for part in name.split("/")
    )


@FAST
@given(text=st.one_of(st.text(max_size=200), st.from_regex(r"\A[0-9a-f]{0,70}(:[a-z]{1,8})?\Z"), REF_NAMES))
def test_resolve_gives_a_full_id_or_one_short_store_error(store, text):
    try:
        oid = resolve(store, text)
    except StoreError as exc:
        one_short_line(exc)
        return
    assert is_full_id(oid) and store.has_object(oid)


def test_resolve_finds_an_object_by_full_id_prefix_and_ref_resolve_always_raises(store):
    """Mutation resolve-always-raises: the property above also holds for a resolve that refuses
    everything, so the three forms a user types are checked to succeed here."""
    oid = store.put_json({"type": "tree", "format": 1, "entries": [], "name": "resolve-probe"})
    set_ref(store, "probe/resolve", oid)
    assert resolve(store, oid) == oid
    assert resolve(store, oid[:16]) == oid
    assert resolve(store, "probe/resolve") == oid
    with pytest.raises(StoreError):
        resolve(store, "probe/none-such")


@FAST
@given(st.binary(max_size=500))
def test_any_bytes_in_a_ref_file_read_as_an_id_or_a_short_error(store, raw):
    path = store.refs_dir / "prop" / "raw"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(raw)
    try:
        oid = _read_ref_file(path, "prop/raw")
    except StoreError as exc:
        one_short_line(exc)
        return
    assert is_full_id(oid) and raw.strip().decode() == oid


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(name=REF_NAMES)
def test_set_ref_then_read_ref_round_trips_or_names_the_conflict(store, name):
    target = store.put_json({"type": "tree", "format": 1, "entries": [], "name": name})
    try:
        set_ref(store, f"p/{name}", target)
    except StoreError as exc:
        assert "conflicts with existing ref" in str(exc)
        return
    assert read_ref(store, f"p/{name}") == target
    assert resolve(store, f"p/{name}") == target


@FAST
@given(st.integers(min_value=4, max_value=64))
def test_an_unambiguous_prefix_resolves_to_its_object(store, k):
    [oid] = [o for o in store.iter_object_ids() if o == hash_bytes(b'{"entries":[],"format":1,"type":"tree"}')]
    assume(not any(o != oid and o.startswith(oid[:k]) for o in store.iter_object_ids()))
    assert store.resolve_prefix(oid[:k]) == oid


# ----------------------------------------------------------------------------- workflow validation
BASE = {"name": "wf", "tasks": ["nist/rect_peg"], "method": "accrue", "budgets": {"env_steps": 100, "eval_every": 50}}
YAMLISH = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(), st.floats(allow_nan=True), st.text(max_size=20)),
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=10), inner, max_size=4)),
    max_leaves=20,
)
FIELDS = [
    ("seed",),
    ("horizon",),
    ("task_features",),
    ("budgets", "env_steps"),
    ("budgets", "eval_every"),
    ("budgets", "num_envs"),
    ("base_policy", "lr"),
    ("base_policy", "finetune_steps"),
    ("base_policy", "demo_quality"),
    ("learner", "beta"),
    ("learner", "lam"),
    ("learner", "actor_lr"),
]


def with_value(path: tuple[str, ...], value) -> dict:
    data = {k: (dict(v) if isinstance(v, dict) else v) for k, v in BASE.items()}
    node = data
    for key in path[:-1]:
        node = node.setdefault(key, {})
    node[path[-1]] = value
    return data


@FAST
@given(field=st.sampled_from(FIELDS), value=YAMLISH)
def test_any_value_in_any_field_parses_or_names_the_field(field, value):
    try:
        wf = parse_workflow(with_value(field, value), "wf.yaml")
    except StageError as exc:
        one_short_line(exc)
        assert str(exc).startswith("wf.yaml: ")
        return
    got = wf.model_dump()
    for key in field:
        got = got[key]
    assert not isinstance(got, bool) and isinstance(got, (int, float)) and math.isfinite(got)


@FAST
@given(field=st.sampled_from(FIELDS), value=st.sampled_from([True, False, math.inf, -math.inf, math.nan]))
def test_numbers_refuse_booleans_infinities_and_nan(field, value):
    with pytest.raises(StageError) as info:
        parse_workflow(with_value(field, value), "wf.yaml")
    assert ".".join(field) in str(info.value)


@FAST
@given(data=st.dictionaries(st.text(max_size=15), YAMLISH, max_size=6))
def test_any_mapping_parses_or_gives_one_short_line(data):
    try:
        parse_workflow({**BASE, **data}, "wf.yaml")
    except StageError as exc:
        one_short_line(exc)
