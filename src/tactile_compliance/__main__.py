"""`python -m tactile_compliance`: the `tactile-compliance` command."""

from tactile_compliance.cli import app

if __name__ == "__main__":  # pragma: no cover
    app(prog_name="tactile-compliance")
