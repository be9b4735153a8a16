"""The TMCL vocabulary: every fact of the firmware manual that code needs, as data, in one home.

``tmcl_server``, ``interpreter`` and ``axes`` all import from here; this package imports
nothing but the standard library, so the codec, the assembler or a host tool can use it
without pulling in the server, a transport library, the axes or the interpreter.

* :mod:`tmcl_spec.numbers`  -- 32-bit value wrapping, units of simulated time
* :mod:`tmcl_spec.commands` -- opcodes, operand symbols, status codes, I/O banks
* :mod:`tmcl_spec.parameters` -- parameter rows (:class:`ParamSpec`), how each moves
  (:class:`Motion`), and their names (AP, GP)
* :mod:`tmcl_spec.modules` -- module types (profiles): which tables a module has, by name
* :mod:`tmcl_spec.family` -- the rows and tables every module of the family shares
* :mod:`tmcl_spec.tmcm6212`, :mod:`tmcl_spec.tmc429_modules`, :mod:`tmcl_spec.tmcm1111`,
  :mod:`tmcl_spec.landungsbruecke` -- the profiles and their tables
"""
