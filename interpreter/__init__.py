"""TMCL programs: the instruction set, the bytecode interpreter, assembler and disassembler.

Nothing here imports the server: the interpreter drives a module through the small
interface it defines itself.
"""
