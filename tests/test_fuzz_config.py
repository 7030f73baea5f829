"""Property-based tests of the configuration loader (issue 21): random TOML documents and random
nested dicts go in; only :class:`ConfigError` (one line) may come out, and whatever is accepted
passes every key's range and survives the TOML round trip.

Settings from ``tests/fuzz_settings.py``: a fixed seed, 60 cases per test in the normal suite (a few
seconds each), ``LIDAR3D_FUZZ_EXAMPLES`` cases under ``make fuzz``.
"""

import math
import operator
import tempfile
from pathlib import Path

import pytest
from fuzz_settings import fuzz_settings
from hypothesis import given
from hypothesis import strategies as st

from lidar3d.config import Choices, Config, ListRange, Range, config_from_dict, config_to_toml, key_specs, load_config
from lidar3d.errors import ConfigError

FUZZ = fuzz_settings(60)
SPECS = {section: {s.path.split(".")[1]: s for s in specs} for section, specs in key_specs()}
NAME = st.builds(operator.add, st.sampled_from("abzAZ_"), st.text(alphabet="abcxyz_09AZ", max_size=9))


# -- values as TOML text ------------------------------------------------------------------------


def _float_text(x: float) -> str:
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return repr(x)


def _string_text(s: str) -> str:
    return '"' + "".join(c if c.isalnum() or c in " ._-/" else f"\\u{ord(c):04x}" for c in s if ord(c) < 0xD800) + '"'


SCALAR = st.one_of(
    st.integers(min_value=-(2**70), max_value=2**70).map(str),
    st.integers(min_value=-3, max_value=3).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(_float_text),
    st.booleans().map(lambda b: "true" if b else "false"),
    st.text(max_size=12).map(_string_text),
    st.sampled_from(["1979-05-27T07:32:00Z", "1979-05-27", "07:32:00", "0x1F", "0o17", "0b101", "1_000", "+.5"]),
)
VALUE = st.recursive(
    SCALAR,
    lambda inner: st.one_of(
        st.lists(inner, max_size=5).map(lambda xs: "[" + ", ".join(xs) + "]"),
        st.dictionaries(NAME, inner, max_size=3).map(
            lambda d: "{" + ", ".join(f"{k} = {v}" for k, v in d.items()) + "}"
        ),
    ),
    max_leaves=8,
)


def _near(bound: float) -> list[float]:
    return [bound, bound - 1e-9, bound + 1e-9, bound - 1, bound + 1, -bound]


def _edge_values(spec) -> st.SearchStrategy[str]:
    """Values on and around the edges of a key's range, as TOML text (the interesting cases)."""
    valid = spec.valid
    if isinstance(valid, Range):
        numbers = [0.0, *_near(valid.low), *_near(valid.high), (valid.low + valid.high) / 2]
        as_int = isinstance(spec.default, int)
        return st.sampled_from(numbers).map(lambda x: str(round(x)) if as_int else _float_text(x))
    if isinstance(valid, ListRange):
        entry = valid.entry if isinstance(valid.entry, Range) else valid.entry[0]
        numbers = st.sampled_from([0.0, *_near(entry.low), *_near(entry.high), (entry.low + entry.high) / 2])
        return st.lists(numbers, max_size=6).map(lambda xs: "[" + ", ".join(_float_text(x) for x in xs) + "]")
    if isinstance(valid, Choices):
        return st.sampled_from([*valid.names, "", "SE3"]).map(_string_text)
    if isinstance(spec.default, bool):
        return st.sampled_from(["true", "false", "1", '"true"'])
    if isinstance(spec.default, str):
        return st.text(max_size=12).map(_string_text)
    return VALUE


@st.composite
def section_lines(draw, section: str) -> list[str]:
    """``key = value`` lines: mostly known keys with values about their range, some of any type."""
    known = SPECS.get(section, {})
    keys = []
    for _ in range(draw(st.integers(0, 5))):
        key = draw(st.sampled_from(sorted(known)) if known and draw(st.integers(0, 19)) else NAME)
        if key not in keys:
            keys.append(key)
    lines = []
    for key in keys:
        spec = known.get(key)
        value = draw(_edge_values(spec) if spec and draw(st.integers(0, 9)) else VALUE)
        lines.append(f"{key} = {value}")
    return lines


@st.composite
def toml_document(draw) -> str:
    lines = []
    sections = []
    for _ in range(draw(st.integers(0, 4))):
        section = draw(st.sampled_from(sorted(SPECS)) if draw(st.integers(0, 9)) else NAME)
        if section not in sections:
            sections.append(section)
    for section in sections:
        if draw(st.integers(0, 19)) == 0:
            section = f"{section}.{draw(NAME)}"  # a nested table
        lines.append(f"[[{section}]]" if draw(st.integers(0, 19)) == 0 else f"[{section}]")
        lines.extend(draw(section_lines(section.split(".")[0])))
    text = "\n".join(lines) + "\n"
    damage = draw(st.integers(0, 9))
    if damage == 0:  # garbage inserted somewhere
        at = draw(st.integers(0, len(text)))
        text = text[:at] + draw(st.text(max_size=20)) + text[at:]
    elif damage == 1:  # a line cut short
        text = text[: draw(st.integers(0, len(text)))]
    return text


def _assert_accepted_config_is_sane(config: Config) -> None:
    for section, specs in key_specs():
        values = getattr(config, section)
        for spec in specs:
            value = getattr(values, spec.path.split(".")[1])
            if isinstance(spec.valid, Range):
                assert spec.valid.contains(value), (spec.path, value)
            elif isinstance(spec.valid, ListRange):
                assert spec.valid.length_ok(len(value)), (spec.path, value)
                assert all(spec.valid.entry_range(i).contains(v) for i, v in enumerate(value)), (spec.path, value)
            elif isinstance(spec.valid, Choices):
                assert value in spec.valid.names, (spec.path, value)
    sensor = config.sensor.resolved_model
    assert config.sensor.min_range_m < sensor.max_range_m
    assert config.segmentation.ground_rows <= sensor.n_rings
    assert config.features.sharp_per_section <= config.features.less_sharp_per_section


@pytest.fixture(scope="module")
def scratch():
    with tempfile.TemporaryDirectory() as folder:
        yield Path(folder) / "fuzz.toml"


def _load(path: Path, data: bytes) -> Config | None:
    path.write_bytes(data)
    try:
        return load_config(path)
    except ConfigError as err:  # anything else fails the test with its traceback
        assert "\n" not in str(err) and str(err).startswith(str(path))
        return None


@FUZZ
@given(text=toml_document())
def test_random_toml_documents_give_config_errors_only(scratch, text):
    config = _load(scratch, text.encode("utf-8", "surrogatepass"))
    if config is not None:
        _assert_accepted_config_is_sane(config)
        scratch.write_text(config_to_toml(config), encoding="utf-8")
        assert load_config(scratch) == config


@FUZZ
@given(data=st.binary(max_size=200))
def test_random_bytes_give_config_errors_only(scratch, data):
    config = _load(scratch, data)
    if config is not None:
        _assert_accepted_config_is_sane(config)


JSON_LIKE = st.recursive(
    st.one_of(
        st.none(),
        st.booleans(),
        st.integers(),
        st.floats(),
        st.text(max_size=8),
    ),
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)),
    max_leaves=6,
)


@st.composite
def nested_dict(draw) -> dict:
    data = {}
    for section in draw(st.lists(st.one_of(st.sampled_from(sorted(SPECS)), st.text(max_size=6)), max_size=3)):
        keys = sorted(SPECS.get(section, {})) or ["x"]
        data[section] = draw(
            st.one_of(
                st.dictionaries(st.one_of(st.sampled_from(keys), st.text(max_size=6)), JSON_LIKE, max_size=4),
                JSON_LIKE,
            )
        )
    return data


@FUZZ
@given(data=nested_dict())
def test_random_dicts_give_config_errors_only(data):
    try:
        config = config_from_dict(data)
    except ConfigError as err:
        assert "\n" not in str(err)
        return
    _assert_accepted_config_is_sane(config)
