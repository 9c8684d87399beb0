"""The venv the measuring scripts under benches/ run in: made on first use, then re-entered."""
import os
import subprocess
import sys
import venv


def ensure_venv(path, packages):
    """Re-runs the calling script inside the venv at `path`, made with `packages` if missing."""
    if os.path.realpath(sys.prefix) == os.path.realpath(path):
        return
    python = os.path.join(path, "bin", "python")
    if not os.path.exists(python):
        venv.create(path, with_pip=True)
        subprocess.check_call([python, "-m", "pip", "install", "-q", *packages])
    os.execv(python, [python, *sys.argv])


def venv_path(out, args):
    """The venv a script writing to `out` uses: `--venv DIR` among `args`, else OUT/.venv."""
    return args[args.index("--venv") + 1] if "--venv" in args else os.path.join(out, ".venv")


def enter(doc, packages):
    """A script's OUT_DIR (its first argument) and arguments, once it runs in its venv (see
    `venv_path`); the usage `doc` and exit when there is no OUT_DIR."""
    args = sys.argv[1:]
    if not args or args[0].startswith("-"):
        sys.exit(doc)
    out = args[0]
    ensure_venv(venv_path(out, args), packages)
    return out, args
