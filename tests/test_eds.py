"""The node's EDS: CiA 306 consistency, the objects issue 6 asks for, PDO mappings,
and limits that agree with the firmware's defaults and the host driver's tables."""

from __future__ import annotations

import configparser

import canopen
import pytest
from canopen.objectdictionary import ODRecord, ODVariable

from feeder.drivers.amplifier import FLYBACK_SHAPES
from feeder.drivers.canopen import DEFAULT_EDS, FAULT_NAMES, MODES, SHAPE_CODES
from feeder.plant.amplifier import AmplifierLimits
from firmware_sim.canopen_node import EDS_PATH, LIMIT_FIELDS
from firmware_sim.firmware import FLYBACK_SHAPES as FIRMWARE_SHAPES
from firmware_sim.firmware import MAX_STEPS, Fault
from firmware_sim.firmware import MODES as FIRMWARE_MODES


@pytest.fixture(scope="module")
def od() -> canopen.ObjectDictionary:
    return canopen.import_od(str(EDS_PATH), 1)


def variable(od: canopen.ObjectDictionary, index: int, subindex: int = 0) -> ODVariable:
    found = od.get_variable(index, subindex)
    assert found is not None, f"0x{index:04X}:{subindex}"
    return found


def test_host_and_node_use_the_same_file() -> None:
    assert DEFAULT_EDS.resolve() == EDS_PATH.resolve()


def test_object_lists_match_the_sections() -> None:
    """CiA 306: every object in the *Objects lists has a section, and vice versa."""
    eds = configparser.RawConfigParser(inline_comment_prefixes=(";",))
    eds.optionxform = str  # type: ignore[assignment,method-assign]
    eds.read(EDS_PATH)
    listed: list[int] = []
    for group in ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects"):
        count = int(eds.get(group, "SupportedObjects"))
        listed += [int(eds.get(group, str(i)), 0) for i in range(1, count + 1)]
    sections = [int(name, 16) for name in eds.sections() if len(name) == 4
                and all(c in "0123456789ABCDEF" for c in name)]
    assert sorted(listed) == sorted(sections)
    assert len(set(listed)) == len(listed)
    for index in sections:  # records: SubNumber = the sub-sections present
        name = f"{index:04X}"
        if eds.has_option(name, "SubNumber"):
            subs = [s for s in eds.sections() if s.startswith(f"{name}sub")]
            assert int(eds.get(name, "SubNumber"), 0) == len(subs), name


def test_communication_objects(od: canopen.ObjectDictionary) -> None:
    assert variable(od, 0x1000).access_type == "ro"
    assert variable(od, 0x1001).access_type == "ro"
    assert variable(od, 0x1017).access_type == "rw"
    identity = od[0x1018]
    assert isinstance(identity, ODRecord)
    assert [identity[i].name for i in range(1, 5)] == \
        ["Vendor-ID", "Product code", "Revision number", "Serial number"]
    assert all(identity[i].access_type == "ro" for i in range(1, 5))
    assert identity[1].default == od.device_information.vendor_number
    assert identity[2].default == od.device_information.product_number
    assert identity[3].default == od.device_information.revision_number
    assert variable(od, 0x1014).default == 0x80 + 1       # $NODEID+0x80


@pytest.mark.parametrize(("index", "access"), [
    (0x2000, "rw"), (0x2001, "rw"), (0x2002, "rw"), (0x2003, "rw"), (0x2005, "rw"),
    (0x2006, "rw"), (0x2010, "rw"), (0x2011, "wo"), (0x2012, "ro"), (0x2013, "ro"),
    (0x2014, "ro"), (0x2015, "ro"), (0x2016, "wo"), (0x2018, "rw"), (0x2019, "ro"),
    (0x2020, "ro"),
])
def test_manufacturer_objects_access(od: canopen.ObjectDictionary, index: int,
                                     access: str) -> None:
    assert variable(od, index).access_type == access


def test_limits_agree_with_the_firmware_defaults(od: canopen.ObjectDictionary) -> None:
    amp = AmplifierLimits()
    limits = {index: (variable(od, index).min, variable(od, index).max) for index in LIMIT_FIELDS}
    assert limits[0x2000] == (round(amp.min_frequency_hz * 1000), round(amp.max_frequency_hz * 1000))
    assert limits[0x2001] == (0, round(amp.max_amplitude_vpp * 1000))
    assert limits[0x2006] == (round(amp.v_min_v * 1000), round(amp.v_max_v * 1000))
    assert limits[0x2010] == (-MAX_STEPS, MAX_STEPS)
    # the longest flyback the firmware can accept: one period at the lowest frequency
    assert limits[0x2003][1] == round(1e9 / amp.min_frequency_hz)
    assert variable(od, 0x2020).default == round(amp.max_amplitude_vpp * 1000)


def test_code_tables_agree_with_the_firmware(od: canopen.ObjectDictionary) -> None:
    assert MODES == FIRMWARE_MODES
    assert (variable(od, 0x2005).min, variable(od, 0x2005).max) == (0, len(MODES) - 1)
    assert SHAPE_CODES[:3] == FLYBACK_SHAPES == FIRMWARE_SHAPES
    assert (variable(od, 0x2002).min, variable(od, 0x2002).max) == (0, len(FLYBACK_SHAPES) - 1)
    assert {int(f): (f.name or "").lower() for f in Fault} == FAULT_NAMES


def pdo_entries(od: canopen.ObjectDictionary, mapping: int) -> list[ODVariable]:
    record = od[mapping]
    assert isinstance(record, ODRecord)
    entries = []
    for sub in range(1, (record[0].default or 0) + 1):
        value = record[sub].default or 0
        target = variable(od, value >> 16, (value >> 8) & 0xFF)
        assert len(target) == value & 0xFF, target.name     # mapped length = object size
        assert target.pdo_mappable, target.name
        entries.append(target)
    assert sum(len(e) for e in entries) <= 64
    return entries


def test_pdo_mappings(od: canopen.ObjectDictionary) -> None:
    assert [e.name for e in pdo_entries(od, 0x1A00)] == \
        ["Step counter", "Status word", "Command acknowledge", "Error register"]
    assert [e.name for e in pdo_entries(od, 0x1600)] == ["Step command", "Command sequence"]
    assert variable(od, 0x1800, 1).default == 0x180 + 1
    assert variable(od, 0x1400, 1).default == 0x200 + 1
    assert variable(od, 0x1800, 2).default == 255           # event-driven
