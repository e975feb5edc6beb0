"""`python -m tactile_compliance.cli`: the same command as `python -m tactile_compliance`."""

from tactile_compliance.cli import app

if __name__ == "__main__":  # pragma: no cover
    app()
