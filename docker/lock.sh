#!/bin/sh
# Regenerate the image's hash-locked requirements (see Dockerfile and
# docs/containers.md, "Reproducible builds"):
#
#   requirements.lock        every runtime dependency of pyproject.toml, direct
#                            and transitive, pinned with the hashes of all its
#                            files (one resolution for every platform: the
#                            image's linux/amd64 and linux/arm64 alike);
#   requirements-build.lock  the build backend of [build-system] (hatchling)
#                            and its dependencies, which build the wheel.
#
#   .venv/bin/pip install -e '.[lock]' && PATH=.venv/bin:$PATH sh docker/lock.sh
#
# Run it after changing a pin in pyproject.toml; tests/test_image_lock.py
# fails until the lock files agree with pyproject.toml again.
set -eu
cd "$(dirname "$0")/.."
set -- --universal --python-version 3.11 --generate-hashes --native-tls --quiet \
    --custom-compile-command "sh docker/lock.sh"
uv pip compile pyproject.toml "$@" --output-file requirements.lock
python3 -c 'import tomllib; print("\n".join(tomllib.load(open("pyproject.toml", "rb"))["build-system"]["requires"]))' \
    | uv pip compile - "$@" --output-file requirements-build.lock
