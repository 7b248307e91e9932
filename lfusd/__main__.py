import sys

try:
    from .cli import main  # light: main() installs the signal handlers before the heavy imports
except KeyboardInterrupt:  # a Ctrl-C in the first milliseconds
    print("lfusd: interrupted; rerun the same command to resume", file=sys.stderr)
    sys.exit(130)

sys.exit(main())
