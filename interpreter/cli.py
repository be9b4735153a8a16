"""``tmcl-asm``: assemble ``.tmc`` source, disassemble ``.bin`` programs, print listings.

    tmcl-asm assemble prog.tmc -o prog.bin [--listing prog.lst] [-I DIR] [--append-stop]
    tmcl-asm disassemble prog.bin [-o prog.tmc] [--listing]
    tmcl-asm list prog.tmc

Every error of a source is printed, one ``file:line:column: message`` line each, in source
order; the exit status is then 4, as ``tmcl`` ends for a file it cannot read, assemble or
decode (the exit codes are the client tools' shared ones: tmcl_spec.package.EXIT_CODES).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import NoReturn

from interpreter.assembler import AssemblyError, assemble_file
from interpreter.disassembler import disassemble, listing
from interpreter.isa import decode_program
from tmcl_spec.package import (
    EXIT_BAD_INPUT,
    EXIT_CODES,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_USAGE,
    add_version_option,
    safe_console,
    with_suggestion,
)


class _OneLineParser(argparse.ArgumentParser):
    """Usage errors in one line, not the usage block."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: {with_suggestion(self, message)} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(prog="tmcl-asm", description="TMCL assembler and disassembler "
                                     "for the TMCM-6212 (TMCL-IDE source and binary formats).",
                            epilog="exit codes:\n" + "\n".join(
                                f"  {code:<4} {meaning}" for code, meaning in EXIT_CODES
                                if code in (EXIT_OK, EXIT_USAGE, EXIT_BAD_INPUT, EXIT_INTERRUPTED)),
                            formatter_class=argparse.RawDescriptionHelpFormatter)
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
        return _run(args)
    except KeyboardInterrupt:
        print("tmcl-asm: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


def _run(args: argparse.Namespace) -> int:
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
        return EXIT_BAD_INPUT
    except (OSError, ValueError) as exc:
        print(f"tmcl-asm: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.command == "list":
        sys.stdout.write(program.listing())
        return EXIT_OK
    output = args.output or args.source.with_suffix(".bin")
    try:  # an output that is a directory, or cannot be written: one line (N9)
        output.write_bytes(program.binary())
        if args.listing:
            args.listing.write_text(program.listing(), encoding="utf-8")
    except OSError as exc:
        print(f"tmcl-asm: cannot write {exc.filename or output}: {exc.strerror or exc}",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    print(f"{args.source}: {len(program.instructions)} commands -> {output}")
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
