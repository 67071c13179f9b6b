#!/usr/bin/env bash
# Install the system libraries glraster loads at run time, through apt, only when missing:
#   libEGL + Mesa's EGL driver (default backend), libOSMesa (fallback backend),
#   Mesa's DRI drivers (llvmpipe), Chromium (headless screenshots of the HTML report in tests),
#   and the venv module of the system's python3.
# Chromium is optional: where apt has no package of it (Ubuntu ships it as a snap), the
# libraries are installed all the same and the screenshot test says it is skipped.
set -euo pipefail

# grep without -q reads all of ldconfig's output, so pipefail never sees a SIGPIPE;
# ldconfig lives in /sbin, which a user's PATH may lack
LDCONFIG=$(command -v ldconfig || echo /sbin/ldconfig)
have_lib() { "$LDCONFIG" -p | grep "$1" >/dev/null; }

missing=()
have_lib 'libEGL.so.1 '       || missing+=(libegl1)
have_lib 'libEGL_mesa.so.0 '  || missing+=(libegl-mesa0)
have_lib 'libOSMesa.so'       || missing+=(libosmesa6)
[ -e /usr/lib/x86_64-linux-gnu/dri/swrast_dri.so ] || [ -n "$(ls /usr/lib/*/dri/swrast_dri.so 2>/dev/null)" ] \
    || missing+=(libgl1-mesa-dri)
# `make` builds its venv with $PYTHON (python3): Debian's and Ubuntu's own python3 has no
# venv module (ensurepip) until python3-venv is installed; another Python is left as it is
python=$(command -v "${PYTHON:-python3}" || true)
if [ -z "$python" ]; then
    missing+=(python3 python3-venv)
elif [[ "$(readlink -f "$python")" == /usr/bin/* ]] && ! "$python" -c 'import ensurepip, venv' 2>/dev/null; then
    missing+=(python3-venv)
fi
browser=()
command -v chromium >/dev/null || command -v chromium-browser >/dev/null || browser=(chromium)

if [ ${#missing[@]} -eq 0 ] && [ ${#browser[@]} -eq 0 ]; then
    exit 0
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null; then SUDO="sudo"; else
        echo "glraster: need root to run: apt-get install -y ${missing[*]} ${browser[*]}" >&2
        exit 1
    fi
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
if [ ${#missing[@]} -gt 0 ]; then
    echo "glraster: installing system libraries: ${missing[*]}"
    $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
if [ ${#browser[@]} -gt 0 ]; then
    # a package of that name that apt can install (not a snap's transitional package)
    if apt-cache show chromium 2>/dev/null | grep '^Version:' >/dev/null \
            && $SUDO apt-get install -y -qq --no-install-recommends chromium; then
        :
    else
        echo "glraster: no chromium from apt here; the HTML report's screenshot test" \
             "(tests/conformance/test_html_report.py) will be skipped" >&2
    fi
fi
