"""``python -m fdigen``: the same as the ``fdigen`` command."""

from fdigen.cli import main

if __name__ == "__main__":  # pragma: no cover
    main(prog_name="fdigen")
