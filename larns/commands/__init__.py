"""One thin argparse adapter per ``larns`` command: each module has ``register(subparsers)``, which
adds its parser and sets ``func`` (called with the parsed arguments, returns an exit code). The
work is done in the packages (:mod:`larns.log`, :mod:`larns.analysis`, :mod:`larns.viz`,
:mod:`larns.fleet`, :mod:`larns.bench`); registering must stay cheap, so heavy imports happen
inside the command functions and ``larns --help`` stays instant.
"""


def doc_of(module: str) -> str:
    """A module's docstring without importing it (no numpy / matplotlib on ``larns --help``)."""
    import ast
    import importlib.util

    spec = importlib.util.find_spec(module)
    with open(spec.origin, encoding="utf-8") as f:
        return ast.get_docstring(ast.parse(f.read()), clean=False) or ""
