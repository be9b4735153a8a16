"""``tmcl-asm``: assemble ``.tmc`` source, disassemble ``.bin`` programs, print listings.

    tmcl-asm assemble prog.tmc -o prog.bin [--listing prog.lst] [-I DIR] [--append-stop]
    tmcl-asm disassemble prog.bin [-o prog.tmc] [--listing]
    tmcl-asm list prog.tmc

Every error of a source is printed, one ``file:line:column: message`` line each, in source
order; the exit status is then 1.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import NoReturn

from interpreter.assembler import AssemblyError, assemble_file
from interpreter.disassembler import disassemble, listing
from interpreter.isa import decode_program
from tmcl_spec.package import add_version_option, safe_console


class _OneLineParser(argparse.ArgumentParser):
    """Usage errors in one line, not the usage block."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(prog="tmcl-asm", description="TMCL assembler and disassembler "
                                     "for the TMCM-6212 (TMCL-IDE source and binary formats).")
    add_version_option(parser)
    sub = parser.add_subparsers(dest="command", required=True)
    asm = sub.add_parser("assemble", help="source to an 8-byte-per-command binary")
    asm.add_argument("source", type=Path)
    asm.add_argument("-o", "--output", type=Path, help="binary file (default: SOURCE with .bin)")
    asm.add_argument("--listing", type=Path, metavar="FILE", help="also write a listing")
    asm.add_argument("-I", "--include", action="append", type=Path, default=[], metavar="DIR",
                     help="search DIR for #include files (repeatable)")
    asm.add_argument("--append-stop", action="store_true",
                     help="end the program with STOP, as the TMCL-IDE does")
    lst = sub.add_parser("list", help="print the listing of a source file")
    lst.add_argument("source", type=Path)
    lst.add_argument("-I", "--include", action="append", type=Path, default=[], metavar="DIR")
    dis = sub.add_parser("disassemble", help="binary back to source with generated labels")
    dis.add_argument("binary", type=Path)
    dis.add_argument("-o", "--output", type=Path, help="write here instead of standard output")
    dis.add_argument("--listing", action="store_true",
                     help="'address: instruction' lines with numeric addresses")
    return parser


def main(argv: list[str] | None = None) -> int:
    safe_console()
    args = build_parser().parse_args(argv)
    try:
        if args.command == "disassemble":
            instructions = decode_program(args.binary.read_bytes())
            text = listing(instructions) if args.listing else disassemble(instructions)
            if args.output:
                args.output.write_text(text, encoding="utf-8")
            else:
                sys.stdout.write(text)
            return 0
        program = assemble_file(args.source, args.include,
                                append_stop=getattr(args, "append_stop", False))
    except AssemblyError as exc:
        print(exc, file=sys.stderr)
        return 1
    except (OSError, ValueError) as exc:
        print(f"tmcl-asm: {exc}", file=sys.stderr)
        return 1
    if args.command == "list":
        sys.stdout.write(program.listing())
        return 0
    output = args.output or args.source.with_suffix(".bin")
    try:  # an output that is a directory, or cannot be written: one line (N9)
        output.write_bytes(program.binary())
        if args.listing:
            args.listing.write_text(program.listing(), encoding="utf-8")
    except OSError as exc:
        print(f"tmcl-asm: cannot write {exc.filename or output}: {exc.strerror or exc}",
              file=sys.stderr)
        return 1
    print(f"{args.source}: {len(program.instructions)} commands -> {output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
