"""Shared plumbing of the command line: JAX cache, JSON output, one-line failures."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import typer


def configure_jax() -> None:
    """Float64 and a persistent compilation cache in a project-local folder.

    The folder is ``$BAYESDOOR_JAX_CACHE`` or ``.jax_cache`` in the working directory, so a
    second run of any command skips most of the compilation.
    """
    import jax

    jax.config.update("jax_enable_x64", True)
    cache = os.environ.get("BAYESDOOR_JAX_CACHE", str(Path.cwd() / ".jax_cache"))
    jax.config.update("jax_compilation_cache_dir", cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


def fail(message: str, code: int = 2) -> typer.Exit:
    """Print a one-line reason on stderr and return the exit to raise."""
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(code)


def emit_json(payload: dict) -> None:
    """The JSON alone on stdout."""
    sys.stdout.write(json.dumps(payload, indent=2, default=float) + "\n")
    sys.stdout.flush()


def check_output_path(path: Path, force: bool) -> None:
    """Refuse to overwrite an existing result unless ``--force``."""
    if path.exists() and not force:
        raise fail(f"{path} already exists; pass --force to overwrite it")
