# Sourced by the test-setup scripts: install a Debian package when a command is missing.
#   ensure_debian_package COMMAND_OR_PATH_TEST PACKAGE "what it is for"
ensure_debian_package() {
    local present="$1" package="$2" purpose="$3"
    if eval "$present"; then
        return 0
    fi
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        echo "installing $package (Debian) for $purpose..." >&2
        DEBIAN_FRONTEND=noninteractive apt-get install -y -q "$package" >&2 \
            || { apt-get update -q >&2 \
                 && DEBIAN_FRONTEND=noninteractive apt-get install -y -q "$package" >&2; }
    else
        echo "$package is not installed (needed for $purpose): sudo apt-get install $package" >&2
        return 1
    fi
}
