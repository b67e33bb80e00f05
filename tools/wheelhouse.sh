#!/usr/bin/env bash
# A wheelhouse for a machine without internet: smol-dsl's wheel and every wheel it needs for
# that machine's Python and platform, or only those missing from its environment.
#
#   tools/wheelhouse.sh --python-version 3.12 --out wheelhouse [--missing-from freeze.txt]
#                       [--arch x86_64] [--glibc 2.28] [--platform TAG]... [--extras video]
#
# Run it here, with internet; carry the folder over; install there with
#   python3.12 -m pip install --no-index --find-links wheelhouse smol-dsl
# (README, "On an offline GPU node"). The work is done by tools/wheelhouse.py, with the
# Python that runs this script (PYTHON, else python3), whose pip downloads for the target.
set -euo pipefail
exec "${PYTHON:-python3}" "$(dirname "$0")/wheelhouse.py" "$@"
