"""sysfs format fields: parsing the kernel's syntax and encoding events with it."""

from __future__ import annotations

import pytest

from hdeem_watch.counters.event_format import encode_event, parse_format
from hdeem_watch.errors import InputError


def test_single_range_and_bit():
    """``config:0-7`` is eight bits from 0; ``config:18`` one bit (sysfs-bus-event_source-devices-format)."""
    assert parse_format("config:0-7\n").ranges == ((0, 7),)
    edge = parse_format("config:18")
    assert (edge.word, edge.ranges, edge.width) == ("config", ((18, 18),), 1)


def test_split_field_fills_ranges_low_bits_first():
    """A split umask (``config:8-15,32-55``, umask_ext4 of uncore_snbep.c) puts bits 0-7 at 8-15, the rest from 32."""
    field = parse_format("config:8-15,32-55")
    assert field.width == 32
    assert field.place(0xAB) == 0xAB << 8
    assert field.place(0x1FF) == (0xFF << 8) | (1 << 32)


def test_encode_uses_the_fields_not_fixed_shifts():
    """A PMU whose umask sits elsewhere encodes elsewhere: the field decides, not a constant."""
    standard = {"event": parse_format("config:0-7"), "umask": parse_format("config:8-15")}
    moved = {"event": parse_format("config:0-7"), "umask": parse_format("config1:0-7")}
    assert encode_event(standard, {"event": 0x04, "umask": 0x03})["config"] == 0x0304
    words = encode_event(moved, {"event": 0x04, "umask": 0x03})
    assert (words["config"], words["config1"]) == (0x04, 0x03)


@pytest.mark.parametrize("text", ["config:", "config:7-0", "config2:0-64", "cfg:0-7", "config:1-2-3", "config:a"])
def test_malformed_format_is_a_one_line_input_error(text):
    """A format file that is not ``<word>:<ranges>`` names the file and the text."""
    with pytest.raises(InputError, match="uncore_imc_0/format/umask"):
        parse_format(text, where="uncore_imc_0/format/umask")


def test_value_too_wide_or_unknown_field_is_refused():
    """A value that does not fit the field, or a field the PMU lacks, is an error (never silently truncated)."""
    fields = {"event": parse_format("config:0-7")}
    with pytest.raises(InputError, match="does not fit"):
        encode_event(fields, {"event": 0x100})
    with pytest.raises(InputError, match="no format field 'umask'"):
        encode_event(fields, {"umask": 1})
