"""Subcommands of the `lfusd` CLI; each module defines ``register(subparsers)``."""
