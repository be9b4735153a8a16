"""The chip cores, one package per chip family: the emulated chips and the chip-specific half
of the firmware that drives them.

* :mod:`axes.chips.tmc42x`: the TMC42x family (TMC4210, TMC429 with its TMC262 drivers) on
  one shared motor engine;
* :mod:`axes.chips.tmc4361a`: the TMC4361A, with the TMCL firmware's core and the evaluation
  board's firmware.

A core is named in :data:`axes.cores.CHIP_CORES` and imported only when a module asks for it;
nothing here is imported by the generic part of :mod:`axes` (docs/architecture.md, "Adding a
chip core").
"""
