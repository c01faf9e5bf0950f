# Sourced by run.sh and session.sh: install the wheels carried in .whl/ into /tmp/site with $PY, the device's
# interpreter, which has no registry to reach. Returns non-zero when they do not install.
install_carried_wheels() {
    if "$PY" -m pip --version >/dev/null 2>&1; then
        "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site \
            .whl/*.whl
    else # a wheel is a zip of its files: without pip, unpacking it installs it as --target would
        local wheel
        for wheel in .whl/*.whl; do "$PY" -m zipfile -e "$wheel" /tmp/site || return 1; done
    fi
}
