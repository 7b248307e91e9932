"""Subcommands of the `lfusd` CLI; each module defines ``register(subparsers)``.

A command's handler is ``run(args)``, an action's in a command group ``run_<action>(args)``
(``run_add``, ``run_make``); it parses nothing itself (the options are typed in
:mod:`lfusd.commands.args`, which also owns the shared ``--rig``), calls one library function and
prints its result."""
