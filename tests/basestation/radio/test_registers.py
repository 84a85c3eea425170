"""One RFM69 register map: the driver and the emulated chip take every address, field and
bit from ``basestation.radio.registers``, and a mode the driver writes is the mode the chip
reports."""

from __future__ import annotations

import ast
import inspect
from types import ModuleType

import pytest

from basestation.radio import RFM69, rfm69
from basestation.radio import registers as regs
from basestation.sim import rfm69 as emulated
from basestation.sim.clock import FakeClock
from basestation.sim.rfm69 import EmulatedRFM69

# The map's vocabulary: every public name it defines, and the prefixes its constants use
# (REG, MODE, OPMODE, IRQ1, IRQ2, PACKET1, DIO0, ...). A module-level name in the driver or
# the emulated chip with one of these prefixes is a register constant.
MAP_NAMES = frozenset(name for name in vars(regs) if name.isupper())
MAP_PREFIXES = frozenset(name.split("_", 1)[0] for name in MAP_NAMES)


def looks_like_register_constant(name: str) -> bool:
    return name.isupper() and (name in MAP_NAMES or name.split("_", 1)[0] in MAP_PREFIXES)


def constants_defined_in(source: str) -> list[str]:
    """Names that ``source`` assigns at module or class level and that look like register
    constants (imports are not definitions)."""
    tree = ast.parse(source)
    scopes: list[list[ast.stmt]] = [tree.body]
    scopes += [node.body for node in ast.walk(tree) if isinstance(node, ast.ClassDef)]
    defined = []
    for body in scopes:
        for statement in body:
            targets: list[ast.expr] = []
            if isinstance(statement, ast.Assign):
                targets = statement.targets
            elif isinstance(statement, ast.AnnAssign):
                targets = [statement.target]
            for target in targets:
                for node in ast.walk(target):
                    if isinstance(node, ast.Name) and looks_like_register_constant(node.id):
                        defined.append(node.id)
    return defined


def test_the_check_catches_a_module_that_defines_its_own_register_constants() -> None:
    source = (
        "from basestation.radio.registers import REG_OPMODE\n"
        "MODE_TX = 3\n"
        "IRQ2_PACKET_SENT: int = 0x08\n"
        "REG_OPMODE_AGAIN = 0x01\n"
        "FIFO_BYTES = 66\n"
        "class Chip:\n"
        "    OPMODE_MODE_MASK = 0x1C\n"
        "TIMEOUT_S = 0.01\n"
    )
    assert constants_defined_in(source) == [
        "MODE_TX",
        "IRQ2_PACKET_SENT",
        "REG_OPMODE_AGAIN",
        "FIFO_BYTES",
        "OPMODE_MODE_MASK",
    ]


@pytest.mark.parametrize("module", [rfm69, emulated], ids=["driver", "emulated chip"])
def test_it_defines_no_register_constant_of_its_own(module: ModuleType) -> None:
    assert constants_defined_in(inspect.getsource(module)) == []
    # What it has under such a name is the map's own object (an import, not a copy).
    borrowed = {
        name: value for name, value in vars(module).items() if looks_like_register_constant(name)
    }
    assert borrowed, "the module uses no name of the map: the check would be empty"
    for name, value in borrowed.items():
        assert name in MAP_NAMES, f"{module.__name__}.{name} is not in the register map"
        assert value is getattr(regs, name), f"{module.__name__}.{name} is not the map's"


# -- the representation, against the datasheet's register values ------------------------------


@pytest.mark.parametrize(
    ("mode", "register_value"),
    [
        (regs.MODE_SLEEP, 0x00),
        (regs.MODE_STANDBY, 0x04),
        (regs.MODE_FS, 0x08),
        (regs.MODE_TX, 0x0C),
        (regs.MODE_RX, 0x10),
    ],
)
def test_a_mode_field_value_is_the_datasheets_regopmode_value(
    mode: int, register_value: int
) -> None:
    assert regs.opmode_with_mode(0x00, mode) == register_value
    assert regs.opmode_mode(register_value) == mode
    # The other bits (SequencerOff, ListenOn) are kept, and the mode field is replaced.
    assert regs.opmode_with_mode(0xFF, mode) == 0xE3 | register_value
    assert regs.opmode_mode(0xE3 | register_value) == mode


def test_dio0_mapping_sits_in_the_top_two_bits_of_regdiomapping1() -> None:
    assert regs.dio_mapping1_with_dio0(0x00, regs.DIO0_RX_PAYLOAD_READY) == 0x40
    assert regs.dio_mapping1_with_dio0(0x3F, regs.DIO0_TX_PACKET_SENT) == 0x3F
    assert regs.dio_mapping1_with_dio0(0xFF, regs.DIO0_RX_SYNC_ADDRESS) == 0xBF
    assert regs.dio0_mapping(0x7F) == regs.DIO0_RX_PAYLOAD_READY
    assert regs.dio0_mapping(0xC0) == regs.DIO0_RX_RSSI


def test_the_driver_writes_the_documented_settings_from_the_map() -> None:
    # docs/protocol.md §1 writes these as hex: the map's bits must add up to the same.
    written = dict(rfm69.RadioSettings().registers())
    assert written[regs.REG_OPMODE] == 0x04
    assert written[regs.REG_DIOMAPPING1] == 0x40
    assert written[regs.REG_SYNCCONFIG] == 0x88
    assert written[regs.REG_PACKETCONFIG1] == 0x94
    assert written[regs.REG_FIFOTHRESH] == 0x8F
    assert written[regs.REG_PACKETCONFIG2] == 0x12
    assert written[regs.REG_PALEVEL] == 0x7F
    assert rfm69.RadioSettings(high_power=False).pa_level == 0x9F


# -- round trip: driver -> SPI -> emulated chip --------------------------------------------------


def test_every_mode_the_driver_sets_is_the_mode_the_emulated_chip_reports() -> None:
    clock = FakeClock()
    chip = EmulatedRFM69(clock=clock)
    radio = RFM69(chip, clock=clock, sleep=clock.sleep)
    radio.begin()
    assert chip.mode == regs.MODE_NAMES[regs.MODE_RX]
    # Every mode from every other one, so no pair of field encodings can hide behind another.
    sequence = [regs.MODE_SLEEP, regs.MODE_STANDBY, regs.MODE_FS, regs.MODE_TX, regs.MODE_RX]
    for previous in sequence:
        for mode in sequence:
            radio.set_mode(previous)
            radio.set_mode(mode)
            assert radio.mode == mode
            assert chip.mode == regs.MODE_NAMES[mode], f"{previous} -> {mode}"
            opmode = chip.peek(regs.REG_OPMODE)
            assert regs.opmode_mode(opmode) == mode
            assert opmode & ~regs.OPMODE_MODE_MASK == 0x00  # sequencer on, listen off
            assert chip.peek(regs.REG_IRQFLAGS1) & regs.IRQ1_MODE_READY


def test_the_emulated_chip_keeps_its_mode_on_a_reserved_mode_value() -> None:
    clock = FakeClock()
    chip = EmulatedRFM69(clock=clock)
    radio = RFM69(chip, clock=clock, sleep=clock.sleep)
    radio.set_mode(regs.MODE_FS)
    radio.write_register(regs.REG_OPMODE, regs.opmode_with_mode(0x00, 7))
    assert chip.mode == regs.MODE_NAMES[regs.MODE_FS]
    assert regs.opmode_mode(radio.read_register(regs.REG_OPMODE)) == regs.MODE_FS
