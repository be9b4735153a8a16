# Sourced by serve.sh and test.sh: the project installed into .venv, set up once and again
# only when something it depends on changed (pyproject.toml, setup.py, the extras asked for,
# $PYTHON).  A stamp in .venv records what the last setup used, so a second start costs a
# checksum, not a reinstall.
#
#   ensure_venv WHO EXTRAS       e.g. ensure_venv serve.sh examples,plot
#
# The Python: $PYTHON if set (it must be >= 3.11), else the first of python3.13, python3.12,
# python3.11 and python3 that is >= 3.11 and has venv.  Messages go to standard error.

MIN_PYTHON="3.11"

_say() { printf '%s: %s\n' "$1" "$2" >&2; }

# A Python >= MIN_PYTHON with venv, as a command name; empty if there is none.
_pick_python() {
    local candidate
    if [ -n "${PYTHON:-}" ]; then
        if "$PYTHON" -c 'import sys, venv; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
            printf '%s' "$PYTHON"
        fi
        return 0
    fi
    for candidate in python3.13 python3.12 python3.11 python3; do
        if command -v "$candidate" >/dev/null 2>&1 &&
            "$candidate" -c 'import sys, venv; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
            printf '%s' "$candidate"
            return 0
        fi
    done
}

# What the setup depends on, as one checksum.
_setup_key() {
    { cat pyproject.toml setup.py 2>/dev/null; printf '%s\n%s\n' "$1" "${PYTHON:-}"; } | cksum | cut -d' ' -f1
}

ensure_venv() {
    local who=$1 extras=$2 stamp key python version
    stamp=".venv/.setup-${extras//,/-}"
    key=$(_setup_key "$extras")
    if [ -x .venv/bin/python ] && [ -f "$stamp" ] && [ "$(head -n 1 "$stamp")" = "$key" ]; then
        _say "$who" "$(sed -n 2p "$stamp") (.venv is up to date)"
        return 0
    fi
    python=$(_pick_python)
    if [ -z "$python" ]; then
        if [ -n "${PYTHON:-}" ]; then
            _say "$who" "error: PYTHON=$PYTHON is not a Python >= $MIN_PYTHON with venv"
        else
            _say "$who" "error: no Python >= $MIN_PYTHON with venv found (tried python3.13, python3.12, python3.11, python3); set PYTHON=/path/to/python3.11 or install one"
        fi
        return 1
    fi
    version=$("$python" -c 'import sys; print("%d.%d.%d" % sys.version_info[:3])')
    _say "$who" "using $python (Python $version, $(command -v "$python"))"
    if [ -x .venv/bin/python ] && [ "$(.venv/bin/python -c 'import sys; print("%d.%d.%d" % sys.version_info[:3])' 2>/dev/null)" = "$version" ]; then
        _say "$who" "setting up .venv again: pyproject.toml, the extras or PYTHON changed"
    else
        _say "$who" "creating .venv with $python ..."
        "$python" -m venv --clear .venv
        rm -f .venv/.setup-*
    fi
    _say "$who" "installing tmcl-sim with the extras $extras into .venv (a minute or two the first time) ..."
    # pip's own lines, a package each: "Collecting ...", "Installing collected packages ..."
    PYTHONUNBUFFERED=1 .venv/bin/python -m pip install --progress-bar off -e ".[$extras]" |
        awk '/^(Collecting|Processing|Installing|Successfully|Obtaining|Building)/ { print "  " $0; fflush() }' >&2
    printf '%s\nusing .venv (Python %s, set up with %s)\n' "$key" "$version" "$python" > "$stamp"
    _say "$who" ".venv is ready"
}
