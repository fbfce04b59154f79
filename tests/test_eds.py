"""The node's EDS: shipped as package data, CiA 306 consistency, the objects issue 6
asks for, PDO mappings, and limits and code tables that agree with the firmware."""

from __future__ import annotations

import configparser
import subprocess
import sys
import zipfile
from importlib import resources
from pathlib import Path

import canopen
import pytest
from canopen.objectdictionary import ODRecord, ODVariable

from feeder.drivers.amplifier import FLYBACK_SHAPES
from feeder.drivers.canopen import fault_names
from feeder.plant.amplifier import AmplifierLimits
from feeder.protocol.anc300 import FAULT_BITS
from feeder.protocol.eds import EDS_FILE, MODES, PACKAGED_EDS, SHAPE_CODES, object_dictionary
from firmware_sim.axis import FLYBACK_SHAPES as FIRMWARE_SHAPES
from firmware_sim.axis import MAX_STEPS
from firmware_sim.canopen_node import LIMIT_FIELDS
from firmware_sim.faults import Fault

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def od() -> canopen.ObjectDictionary:
    return object_dictionary(1)


def variable(od: canopen.ObjectDictionary, index: int, subindex: int = 0) -> ODVariable:
    found = od.get_variable(index, subindex)
    assert found is not None, f"0x{index:04X}:{subindex}"
    return found


def eds_sections(eds: str = EDS_FILE) -> configparser.RawConfigParser:
    parser = configparser.RawConfigParser(inline_comment_prefixes=(";",))
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    parser.read_string(resources.files("feeder.protocol").joinpath(eds).read_text(encoding="ascii"))
    return parser


def test_each_eds_exists_once_as_package_data() -> None:
    found = sorted(
        p.relative_to(ROOT).as_posix()
        for p in ROOT.rglob("*.eds")
        if ".venv" not in p.parts and "build" not in p.parts
    )
    assert found == sorted(f"feeder/protocol/{name}" for name in PACKAGED_EDS)
    assert 'feeder.protocol" = ["*.eds"]' in (ROOT / "pyproject.toml").read_text()


@pytest.mark.timeout(180)
def test_a_built_wheel_carries_the_eds_and_reads_it_from_elsewhere(tmp_path: Path) -> None:
    """A non-editable install: the wheel holds the EDS, and an interpreter whose only
    ``feeder`` is that wheel (run from another directory) loads the dictionary."""
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(tmp_path),
            str(ROOT),
        ],
        check=True,
        capture_output=True,
        cwd=tmp_path,
    )
    (wheel,) = tmp_path.glob("feeder-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        assert {f"feeder/protocol/{name}" for name in PACKAGED_EDS} <= set(archive.namelist())
        archive.extractall(tmp_path / "site")
    site = str(tmp_path / "site")
    probe = (
        "import feeder.protocol.eds as e; od = e.object_dictionary(3); "
        f"assert e.__file__.startswith({site!r}), e.__file__; "
        "print(od['COB-ID EMCY'].default, od['Mode'].value_descriptions[3])"
    )
    result = subprocess.run(
        [sys.executable, "-c", probe],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={"PYTHONPATH": site},
        check=True,
    )
    assert result.stdout.split() == [str(0x80 + 3), "stp"]


@pytest.mark.parametrize("eds", PACKAGED_EDS)
def test_object_lists_match_the_sections(eds: str) -> None:
    """CiA 306: every object in the *Objects lists has a section, and vice versa."""
    parsed = eds_sections(eds)
    listed: list[int] = []
    for group in ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects"):
        count = int(parsed.get(group, "SupportedObjects"))
        listed += [int(parsed.get(group, str(i)), 0) for i in range(1, count + 1)]
    sections = [
        int(name, 16)
        for name in parsed.sections()
        if len(name) == 4 and all(c in "0123456789ABCDEF" for c in name)
    ]
    assert sorted(listed) == sorted(sections)
    assert len(set(listed)) == len(listed)
    for index in sections:  # records: SubNumber = the sub-sections present
        name = f"{index:04X}"
        if parsed.has_option(name, "SubNumber"):
            subs = [s for s in parsed.sections() if s.startswith(f"{name}sub")]
            assert int(parsed.get(name, "SubNumber"), 0) == len(subs), name


def test_communication_objects(od: canopen.ObjectDictionary) -> None:
    assert variable(od, 0x1000).access_type == "ro"
    assert variable(od, 0x1001).access_type == "ro"
    assert variable(od, 0x1017).access_type == "rw"
    identity = od[0x1018]
    assert isinstance(identity, ODRecord)
    assert [identity[i].name for i in range(1, 5)] == [
        "Vendor-ID",
        "Product code",
        "Revision number",
        "Serial number",
    ]
    assert all(identity[i].access_type == "ro" for i in range(1, 5))
    assert identity[1].default == od.device_information.vendor_number
    assert identity[2].default == od.device_information.product_number
    assert identity[3].default == od.device_information.revision_number
    assert variable(od, 0x1014).default == 0x80 + 1  # $NODEID+0x80


@pytest.mark.parametrize(
    ("index", "access"),
    [
        (0x2000, "rw"),
        (0x2001, "rw"),
        (0x2002, "rw"),
        (0x2003, "rw"),
        (0x2005, "rw"),
        (0x2006, "rw"),
        (0x2010, "rw"),
        (0x2011, "wo"),
        (0x2012, "ro"),
        (0x2013, "ro"),
        (0x2014, "ro"),
        (0x2015, "ro"),
        (0x2016, "wo"),
        (0x2018, "rw"),
        (0x2019, "ro"),
        (0x2020, "ro"),
    ],
)
def test_manufacturer_objects_access(od: canopen.ObjectDictionary, index: int, access: str) -> None:
    assert variable(od, index).access_type == access


def test_limits_agree_with_the_firmware_defaults(od: canopen.ObjectDictionary) -> None:
    amp = AmplifierLimits()
    limits = {name: (od[name].min, od[name].max) for name in LIMIT_FIELDS}
    assert limits["Frequency"] == (round(amp.min_frequency_hz * 1000), round(amp.max_frequency_hz * 1000))
    assert limits["Amplitude"] == (0, round(amp.max_amplitude_vpp * 1000))
    assert limits["Offset"] == (round(amp.v_min_v * 1000), round(amp.v_max_v * 1000))
    assert limits["Step command"] == (-MAX_STEPS, MAX_STEPS)
    # the longest flyback the firmware can accept: one period at the lowest frequency
    assert limits["Flyback time"][1] == round(1e9 / amp.min_frequency_hz)
    assert variable(od, 0x2020).default == round(amp.max_amplitude_vpp * 1000)


def test_code_tables_agree_with_the_firmware(od: canopen.ObjectDictionary) -> None:
    assert (variable(od, 0x2005).min, variable(od, 0x2005).max) == (0, len(MODES) - 1)
    assert SHAPE_CODES[:3] == FLYBACK_SHAPES == FIRMWARE_SHAPES
    assert (variable(od, 0x2002).min, variable(od, 0x2002).max) == (0, len(FLYBACK_SHAPES) - 1)
    assert {(f.name or "").lower(): int(f) for f in Fault} == FAULT_BITS
    assert fault_names(0b101) == ("watchdog", "overtemp")
    assert fault_names(1 << 9) == ("fault9",)


def test_code_tables_are_attached_to_the_dictionary(od: canopen.ObjectDictionary) -> None:
    assert od["Mode"].value_descriptions == dict(enumerate(MODES))
    assert od["Flyback shape"].value_descriptions == dict(enumerate(SHAPE_CODES))
    assert od["Status word"].bit_definitions == {
        "moving": [0],
        "stepping mode": [1],
        "fault": [2],
        "refused": [3],
    }
    assert od["Fault word"].bit_definitions == {
        name: [mask.bit_length() - 1] for name, mask in FAULT_BITS.items()
    }
    assert 1 << od["Fault word"].bit_definitions["overtemp"][0] == int(Fault.OVERTEMP)


def pdo_entries(od: canopen.ObjectDictionary, mapping: int) -> list[ODVariable]:
    record = od[mapping]
    assert isinstance(record, ODRecord)
    entries = []
    for sub in range(1, (record[0].default or 0) + 1):
        value = record[sub].default or 0
        target = variable(od, value >> 16, (value >> 8) & 0xFF)
        assert len(target) == value & 0xFF, target.name  # mapped length = object size
        assert target.pdo_mappable, target.name
        entries.append(target)
    assert sum(len(e) for e in entries) <= 64
    return entries


def test_pdo_mappings(od: canopen.ObjectDictionary) -> None:
    assert [e.name for e in pdo_entries(od, 0x1A00)] == [
        "Step counter",
        "Status word",
        "Command acknowledge",
        "Error register",
    ]
    assert [e.name for e in pdo_entries(od, 0x1600)] == ["Step command", "Command sequence"]
    assert variable(od, 0x1800, 1).default == 0x180 + 1
    assert variable(od, 0x1400, 1).default == 0x200 + 1
    assert variable(od, 0x1800, 2).default == 255  # event-driven
