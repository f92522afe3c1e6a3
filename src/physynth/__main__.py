"""``python -m physynth``: the same as the ``physynth`` command."""

from .cli import main

if __name__ == "__main__":
    main()
