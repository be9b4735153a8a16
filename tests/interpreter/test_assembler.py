"""Assembler, disassembler, include files and tmcl-asm."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from interpreter.assembler import INCLUDE_DIR, AssemblyError, assemble, assemble_file
from interpreter.cli import main as tmcl_asm
from interpreter.disassembler import disassemble, listing
from interpreter.interrupts import INTERRUPT_VECTORS
from interpreter.isa import Instruction, decode_program, encode_program
from tests.helpers.instructions import canonical_instructions
from tmcl_spec import tmcl_ide
from tmcl_spec.commands import Opcode
from tmcl_spec.tmcm6212 import AXIS_PARAMETERS, BANK0_PARAMETERS, BANK3_PARAMETERS

ROOT = Path(__file__).resolve().parents[2]
VECTOR = Path(__file__).resolve().parents[1] / "vectors" / "pytrinamic_test.bin"


def vector_bytes() -> bytes:
    return VECTOR.read_bytes()


# -- the real IDE binary ----------------------------------------------------------------------

def test_pytrinamic_vector_disassembles_to_its_listing() -> None:
    # The vector README prints "MVP REL, 0, 200" for addresses 3 and 9, but the records hold
    # 00 00 C8 00 = 51200 (and FF FF 38 00 = -51200 at address 6): the bytes are the truth.
    assert listing(decode_program(vector_bytes())) == (
        "    0: VECT 3, 5\n"
        "    1: EI 3\n"
        "    2: EI 255\n"
        "    3: MVP REL, 0, 51200\n"
        "    4: JA 4\n"
        "    5: VECT 3, 8\n"
        "    6: MVP REL, 0, -51200\n"
        "    7: RETI\n"
        "    8: VECT 3, 5\n"
        "    9: MVP REL, 0, 51200\n"
        "    10: RETI\n")


def test_pytrinamic_vector_source_round_trip() -> None:
    data = vector_bytes()
    source = disassemble(decode_program(data))
    assert "L1:\n    JA L1\n" in source
    assert assemble(source).binary() == data


# -- assembler features -------------------------------------------------------------------------

def test_manual_example_binaries() -> None:
    """Binary forms printed in the manual (§3.6): the 7 command bytes match."""
    cases = {
        "ROR 0, 51200": "01 00 00 00 00 c8 00",
        "MVP ABS, 0, 9000": "04 00 00 00 00 23 28",
        "CALC MUL, -5000": "13 02 00 ff ff ec 78",
        "COMP 1000": "14 00 00 00 00 03 e8",
        "Label: JC GE, Label + 10": "15 05 00 00 00 00 0a",
        "CSUB 100": "17 00 00 00 00 00 64",
        "WAIT POS, 0, 0": "1b 01 00 00 00 00 00",
        "CALCX MUL": "21 02 00 00 00 00 00",
        "AGP 42, 2": "23 2a 02 00 00 00 00",
        "CLE ETO": "24 01 00 00 00 00 00",
        "EI 255": "19 ff 00 00 00 00 00",
        "SIO 3, 2, 1": "0e 03 02 00 00 00 01",
    }
    for source, expected in cases.items():
        assert assemble(source).binary()[:7].hex(" ") == expected, source


def test_labels_constants_comments_and_case() -> None:
    program = assemble("""
        // the TMCL-IDE's style
        MaxSpeed = 50000
        Twice = MaxSpeed * 2 + $10 - 0x10   // expressions, $hex and 0x hex
    loop :
        sap 4, 0, maxspeed
        MVP abs , 0 , Twice
        wait pos, 0, 0
        jc Ge, LOOP
        Func: JA loop
    """)
    assert program.instructions == [
        Instruction(Opcode.SAP, 4, 0, 50000),
        Instruction(Opcode.MVP, 0, 0, 100000),
        Instruction(Opcode.WAIT, 1, 0, 0),
        Instruction(Opcode.JC, 5, 0, 0),
        Instruction(Opcode.JA, 0, 0, 0),
    ]
    assert program.labels == {"loop": 0, "Func": 4}
    assert program.constants == {"MaxSpeed": 50000, "Twice": 100000}


def test_unsigned_values_wrap_to_signed() -> None:
    assert assemble("CALC AND, 0xFFFFFFFF").instructions[0].value == -1


def test_include_files_from_the_source_directory(tmp_path: Path) -> None:
    (tmp_path / "Consts.INC").write_text("Target = 1234\n")
    (tmp_path / "main.tmc").write_text("#include consts.inc\n#include Interrupts.inc\n"
                                       "MVP ABS, 0, Target\nEI TI_GLOBAL\n")
    program = assemble_file(tmp_path / "main.tmc")
    assert program.instructions == [Instruction(Opcode.MVP, 0, 0, 1234), Instruction(Opcode.EI, 255)]


def test_manual_symbolic_constants_example() -> None:
    """§7.3, with the shipped TMCLParam.tmc."""
    program = assemble("""
        #include TMCLParam.tmc
        MaxSpeed = 50000
        MaxAcc = 10000
        Position0 = 0
        Position1 = 500000
        SAP APMaxPositioningSpeed, Motor0, MaxSpeed
        SAP APMaxAcceleration, Motor0, MaxAcc
    MainLoop:
        MVP ABS, Motor0, Position1
        WAIT POS, Motor0, 0
        MVP ABS, Motor0, Position0
        WAIT POS, Motor0, 0
        JA MainLoop
    """)
    assert program.instructions[:2] == [Instruction(Opcode.SAP, 4, 0, 50000),
                                        Instruction(Opcode.SAP, 5, 0, 10000)]


@pytest.mark.parametrize(("source", "where", "message"), [
    ("  FOO 1, 2", "1:3", "unknown mnemonic 'FOO'"),
    ("JA Nowhere", "1:4", "undefined symbol 'Nowhere'"),
    ("X: STOP\n  x: STOP", "2:3", "duplicate label 'x'"),
    ("SAP 300, 0, 1", "1:5", "out of range 0..255"),
    ("MVP ABS, 0", "1:1", "MVP takes 3 operand(s), got 2"),
    ("RSUB 1", "1:1", "RSUB takes 0 operand(s), got 1"),
    ("CALC SWAP, 1", "1:6", "SWAP is not allowed in CALC"),
    ("JA 7000", "1:4", "outside program memory"),
    ("COMP 0x100000000", "1:6", "does not fit 32 bits"),
    ("WAIT 9, 0, 0", "1:6", "out of range for WAIT"),
    ("A = B\nB = A\nCOMP A", "1:1", "depends on itself"),
    ("#include missing.inc", "1:10", "not found"),
    ("COMP 1 +", "1:8", "missing operand after '+'"),
])
def test_errors_point_at_file_line_and_column(source: str, where: str, message: str) -> None:
    with pytest.raises(AssemblyError) as info:
        assemble(source, "prog.tmc")
    assert str(info.value).startswith(f"prog.tmc:{where}: ")
    assert message in str(info.value)


# -- disassembler ---------------------------------------------------------------------------

@given(st.lists(canonical_instructions(), max_size=40))
def test_disassembly_assembles_to_the_same_program(program: list[Instruction]) -> None:
    assert assemble(disassemble(program)).instructions == program


def test_disassembly_keeps_non_canonical_fields_visible() -> None:
    text = disassemble([Instruction(Opcode.RETI, 255), Instruction(99, 1, 2, 3)])
    assert "RETI  // also type 255" in text
    assert "// opcode 99, type 1, motor 2, value 3" in text


def test_binary_records_and_checksums() -> None:
    data = encode_program([Instruction(Opcode.STOP)])
    assert data.hex(" ") == "1c 00 00 00 00 00 00 1c"
    with pytest.raises(ValueError, match="checksum"):
        decode_program(data[:-1] + b"\x00")
    with pytest.raises(ValueError, match="multiple of 8"):
        decode_program(data[:-1])


# -- include files against the tables ------------------------------------------------------

def test_include_files_are_generated_from_the_tables() -> None:
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / "gen_includes.py"), "--check"],
                            capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr


def _constants(name: str) -> dict[str, int]:
    pairs = re.findall(r"^(\w+) = (-?\d+)", (INCLUDE_DIR / name).read_text(), re.MULTILINE)
    return {key: int(value) for key, value in pairs}


def test_include_files_cover_every_parameter_and_vector() -> None:
    params = _constants("TMCLParam.tmc")
    ap = {v for k, v in params.items() if k.startswith("AP") and k not in tmcl_ide.PARAMETER_VALUES}
    assert ap == set(AXIS_PARAMETERS) | set(tmcl_ide.AXIS_PARAMETERS.values())
    assert {k: params[k] for k in tmcl_ide.SYMBOLS} == tmcl_ide.SYMBOLS
    gp = [v for k, v in params.items() if k.startswith("GP")]
    assert sorted(gp) == sorted([*BANK0_PARAMETERS, *BANK3_PARAMETERS])
    assert params["APMaxPositioningSpeed"] == 4 and params["APMaxAcceleration"] == 5  # §7.3 names
    assert _constants("Interrupts.inc") == {name: n for n, (name, _) in INTERRUPT_VECTORS.items()}
    assert _constants("Interrupts.inc")["TI_TIMER0"] == 0  # the manual's §3.5.6.4 names
    assert _constants("Interrupts.inc")["TI_GLOBAL"] == 255


def _ide_program() -> str:
    """One instruction per name of the TMCL-IDE's TMCLParam.tmc, each in the field it names."""
    lines = ["#include TMCLParam.tmc"]
    lines += [f"SAP {name}, Motor0, 0" for name in tmcl_ide.AXIS_PARAMETERS]
    lines += [f"GAP 1, {name}" for name in tmcl_ide.MOTORS]
    lines += [f"SAP 0, 0, {name}" for name in tmcl_ide.PARAMETER_VALUES]
    return "\n".join(lines) + "\n"


def test_every_tmcl_ide_name_assembles_to_the_ides_number() -> None:
    """A program written with the TMCL-IDE's include (its names, generated from
    tmcl_spec/tmcl_ide.py) assembles with ours, each name standing for the IDE's number."""
    program = assemble(_ide_program()).instructions
    expected = ([(Opcode.SAP, n, 0, 0) for n in tmcl_ide.AXIS_PARAMETERS.values()]
                + [(Opcode.GAP, 1, n, 0) for n in tmcl_ide.MOTORS.values()]
                + [(Opcode.SAP, 0, 0, n) for n in tmcl_ide.PARAMETER_VALUES.values()])
    assert [(i.opcode, i.type, i.motor, i.value) for i in program] == expected
    assert len(program) == len(tmcl_ide.SYMBOLS)


def test_ide_and_own_names_are_aliases() -> None:
    """Where the IDE names a number otherwise, both names assemble to it (ours stay)."""
    program = assemble("""
        #include TMCLParam.tmc
        SAP APRampMode, Motor0, APVRampModeVelocity
        GAP APNextPosition, Motor1
        GAP APTargetPosition, Motor1
        GAP APActualVelocity, Motor0
        GAP APActualSpeed, Motor0
        GAP APStallguardThresholdLevel, Motor2
        SAP APMixedDecay, Motor0, APVMixedDecayPermanent
    """).instructions
    assert [(i.type, i.motor, i.value) for i in program] == [
        (138, 0, 2), (0, 1, 0), (0, 1, 0), (3, 0, 0), (3, 0, 0), (205, 2, 0), (203, 0, -1)]


def test_tmcl_asm_assembles_an_ide_program(tmp_path: Path) -> None:
    source = tmp_path / "ide.tmc"
    source.write_text(_ide_program())
    assert tmcl_asm(["assemble", str(source), "-o", str(tmp_path / "ide.bin")]) == 0
    assert len(decode_program((tmp_path / "ide.bin").read_bytes())) == len(tmcl_ide.SYMBOLS)


# -- tmcl-asm -----------------------------------------------------------------------------------

def test_tmcl_asm_assemble_list_disassemble(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    source = tmp_path / "prog.tmc"
    source.write_text("Loop: CALC ADD, 1\n  JA Loop\n")
    assert tmcl_asm(["assemble", str(source), "--listing", str(tmp_path / "prog.lst"),
                     "--append-stop"]) == 0
    binary = tmp_path / "prog.bin"
    assert decode_program(binary.read_bytes())[-1] == Instruction(Opcode.STOP)
    assert "    1  16 00 00 00 00 00 00 16  " in (tmp_path / "prog.lst").read_text()
    capsys.readouterr()
    assert tmcl_asm(["disassemble", str(binary)]) == 0
    assert capsys.readouterr().out == "L1:\n    CALC ADD, 1\n    JA L1\n    STOP\n"
    assert tmcl_asm(["disassemble", "--listing", str(binary)]) == 0
    assert "    1: JA 0\n" in capsys.readouterr().out
    assert tmcl_asm(["list", str(source)]) == 0
    assert "JA Loop" in capsys.readouterr().out


def test_tmcl_asm_reports_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    source = tmp_path / "bad.tmc"
    source.write_text("STOP\n  JA Missing\n")
    assert tmcl_asm(["assemble", str(source)]) == 4  # as tmcl for a file it cannot assemble
    assert f"{source}:2:6: undefined symbol 'Missing'" in capsys.readouterr().err


# -- every error in one run; includes kept to their folders; limits ----------------------------

SEVERAL_ERRORS = """\
// five mistakes
Speed = 1000
  FLY 1, 2
SAP 4, 0, Speed
ROR 0 1 20000
JA Nowhere
Bad = 1 +
COMP Bad
SAP 300, 0, 1
Loop: JA Loop
Loop: STOP
"""


def test_every_error_of_a_source_in_one_run_in_line_order(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    source = tmp_path / "several.tmc"
    source.write_text(SEVERAL_ERRORS)
    assert tmcl_asm(["assemble", str(source)]) == 4  # as tmcl for a file it cannot assemble
    lines = capsys.readouterr().err.splitlines()
    assert lines == [
        f"{source}:3:3: unknown mnemonic 'FLY'",
        f"{source}:5:1: ROR takes 2 operand(s), got 3 (the manual's form: ROR <axis>, <velocity>)",
        f"{source}:6:4: undefined symbol 'Nowhere'",
        f"{source}:7:9: missing operand after '+'",  # and COMP Bad says nothing more
        f"{source}:9:5: operand '300' = 300 out of range 0..255",
        f"{source}:11:1: duplicate label 'Loop' (first defined at {source}:10:1)",
    ]
    assert not (tmp_path / "several.bin").exists()


def test_errors_in_include_files_come_where_they_are_included(tmp_path: Path) -> None:
    (tmp_path / "part.inc").write_text("X = 1\nBROKEN 3\n")
    (tmp_path / "main.tmc").write_text("STOP 1\n#include part.inc\nJA Missing\n")
    with pytest.raises(AssemblyError) as info:
        assemble_file(tmp_path / "main.tmc")
    assert [str(e.location) for e in info.value.errors] == [
        f"{tmp_path}/main.tmc:1:1", f"{(tmp_path / 'part.inc').resolve()}:2:1", f"{tmp_path}/main.tmc:3:4"]


def test_includes_resolve_only_in_the_source_tree_the_I_folders_and_the_shipped_one(tmp_path: Path) -> None:
    project, elsewhere, extra = tmp_path / "project", tmp_path / "elsewhere", tmp_path / "extra"
    for folder in (project / "sub", elsewhere, extra):
        folder.mkdir(parents=True)
    secret = "SECRET_VALUE_not_for_errors"
    (elsewhere / "secret.inc").write_text(f"{secret} 1, 2\n")
    (project / "sub" / "ok.inc").write_text("Near = 7\n")
    (extra / "lib.inc").write_text("Far = 9\n")
    (project / "link.inc").symlink_to(elsewhere / "secret.inc")
    main = project / "main.tmc"
    main.write_text("#include sub/ok.inc\n#include lib.inc\n#include TMCLParam.tmc\nCOMP Near + Far\n")
    assert assemble_file(main, [extra]).instructions == [Instruction(Opcode.COMP, 0, 0, 16)]
    for name in (str(elsewhere / "secret.inc"), "../elsewhere/secret.inc", "link.inc", "/etc/passwd",
                 "/proc/self/environ"):
        main.write_text(f"#include {name}\nSTOP\n")
        with pytest.raises(AssemblyError) as info:
            assemble_file(main, [extra])
        message = str(info.value)
        assert message == (f"{main}:1:10: include file {name!r} is outside the source's folder, "
                           "the -I folders and the shipped include folder"), message
        assert secret not in message


def _hostile(tmp_path: Path) -> dict[str, Path]:
    """The sources of issue 27: each must end in one clear line (the limits)."""
    cases: dict[str, Path] = {}
    fan = tmp_path / "fan"
    fan.mkdir()
    for i in range(31):  # every file includes all the files after it: 2**30 inclusions
        (fan / f"f{i}.inc").write_text("".join(f"#include f{j}.inc\n" for j in range(i + 1, 31)))
    (fan / "main.tmc").write_text("#include f0.inc\nSTOP\n")
    cases["fan-out"] = fan / "main.tmc"
    wide = tmp_path / "wide"
    wide.mkdir()
    for i in range(12):  # shallower, but still thousands of inclusions
        (wide / f"w{i}.inc").write_text("".join(f"#include w{j}.inc\n" for j in range(i + 1, 12)))
    (wide / "main.tmc").write_text("#include w0.inc\n")
    cases["wide fan-out"] = wide / "main.tmc"
    chain = tmp_path / "chain"
    chain.mkdir()
    for i in range(200):
        (chain / f"c{i}.inc").write_text(f"#include c{i + 1}.inc\n" if i < 199 else "X = 1\n")
    (chain / "main.tmc").write_text("#include c0.inc\n")
    cases["deep include chain"] = chain / "main.tmc"
    sources = {
        "multiplication bomb": "A = " + "*".join(["99999999"] * 40) + "\nB = " + "*".join(["A"] * 40)
                               + "\nC = " + "*".join(["B"] * 40) + "\n",
        "huge shift": "COMP 1 << 10000000000\n",
        "forward constant chain": "".join(f"A{i} = A{i + 1} + 1\n" for i in range(5000)) + "A5000 = 0\n",
        "long constant chain": "A0 = 0\n" + "".join(f"A{i + 1} = A{i} + 1\n" for i in range(100_000)),
        "huge expression": "COMP " + "+".join(["1"] * 500_000) + "\n",
        "deep parentheses": "COMP " + "(" * 100_000 + "1" + ")" * 100_000 + "\n",
        "many lines": "STOP\n" * 200_000,
    }
    for name, text in sources.items():
        path = tmp_path / (name.replace(" ", "-") + ".tmc")
        path.write_text(text)
        cases[name] = path
    return cases


def test_hostile_sources_end_in_one_clear_line(tmp_path: Path) -> None:
    for name, source in _hostile(tmp_path).items():
        result = subprocess.run([sys.executable, "-m", "interpreter.cli", "assemble", str(source)],
                                capture_output=True, text=True, timeout=60)
        lines = result.stderr.splitlines()
        assert result.returncode == 4 and len(lines) == 1, (name, result.stderr[-2000:])
        assert re.match(rf"{re.escape(str(source.parent))}/\S+:\d+:\d+: \S", lines[0]), (name, lines)
        assert "Traceback" not in result.stderr and "Error:" not in lines[0], (name, lines)
