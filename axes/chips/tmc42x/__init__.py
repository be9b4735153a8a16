"""The TMC42x family: the TMC4210 and the TMC429 (with the TMC262 driver of the TMC429
modules), built on one motor engine.

* :mod:`~axes.chips.tmc42x.registers`: the register map, bits and number helpers;
* :mod:`~axes.chips.tmc42x.law`: a motor's motion law, one clk32 tick at a time
  (``MotorLaw``), and its fast shortcut, which must equal it:
  :mod:`~axes.chips.tmc42x.fast_steady` (stretches at a constant velocity) and
  :mod:`~axes.chips.tmc42x.fast_ramps` (batches of ramp ticks), joined with the axis
  registers in :mod:`~axes.chips.tmc42x.engine` (``MotorEngine``);
* :mod:`~axes.chips.tmc42x.tmc4210`, :mod:`~axes.chips.tmc42x.tmc429`,
  :mod:`~axes.chips.tmc42x.tmc262`: the chips;
* :mod:`~axes.chips.tmc42x.units`: the datasheet's unit conversions;
* :mod:`~axes.chips.tmc42x.firmware`: the firmware routines both cores share
  (``TMC42xDriver``), :mod:`~axes.chips.tmc42x.tmc4210_firmware` and
  :mod:`~axes.chips.tmc42x.tmc429_firmware`: the cores ``tmc4210`` and ``tmc429``.

docs/motion.md and docs/tmc429.md have the modelling choices.
"""
