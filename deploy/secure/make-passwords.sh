#!/bin/sh
# Passwords for ovis's secure Zenoh profile, and each user's client configuration.
#
#   deploy/secure/make-passwords.sh OUT_DIR [USER]...
#   (default users: the six services capture preprocess label pose calibrator fusion,
#   each its own identity, and the people: operator viewer)
#
# For each USER (letters, digits, '_', '.', '-'):
#   - OUT_DIR/passwords.txt (the router's dictionary_file, "user:password" lines, mode
#     600) keeps the user's line if there is one (a password you wrote by hand is kept),
#     else gets a new random password;
#   - OUT_DIR/USER.json5 (mode 600) is client.json5 (next to this script) with the user's
#     name and password filled in: the config_file of that user's ovis TOML.
# What a user may do is set by the router's access_control (router.json5) by user name:
# a new user also needs its name in a subject there. Never commit OUT_DIR.
set -eu

usage() {
    sed -n '2,16p' "$0" | sed 's/^# \{0,1\}//' >&2
    exit 2
}

[ $# -ge 1 ] || usage
case "$1" in -h | --help | -*) usage ;; esac
out=$1
shift
[ $# -gt 0 ] || set -- capture preprocess label pose calibrator fusion operator viewer
here=$(cd "$(dirname "$0")" && pwd)
template="$here/client.json5"
[ -f "$template" ] || {
    echo "make-passwords.sh: $template is missing" >&2
    exit 1
}

umask 077
mkdir -p "$out"
dict="$out/passwords.txt"
touch "$dict"
chmod 600 "$dict"

random_password() {
    if command -v openssl >/dev/null 2>&1; then
        openssl rand -hex 24
    else
        od -An -N24 -tx1 /dev/urandom | tr -d ' \n'
    fi
}

for user in "$@"; do
    case "$user" in '' | *[!A-Za-z0-9_.-]*)
        echo "make-passwords.sh: user name '$user' must be letters, digits, '_', '.' or '-'" >&2
        exit 2
        ;;
    esac
    password=$(awk -F: -v u="$user" '$1 == u { sub(/^[^:]*:/, ""); print; exit }' "$dict")
    if [ -z "$password" ]; then
        password=$(random_password)
        printf '%s:%s\n' "$user" "$password" >>"$dict"
        echo "added $user to $dict"
    else
        echo "kept $user's password in $dict"
    fi
    case "$password" in *'"'* | *'\'*)
        echo "make-passwords.sh: $user's password may not contain '\"' or '\\'" >&2
        exit 2
        ;;
    esac
    # literal replacement (a password may hold characters special to sed)
    OVIS_USER=$user OVIS_PASSWORD=$password awk '
        function put(s, from, to,    i, r) {
            r = ""
            while ((i = index(s, from)) > 0) {
                r = r substr(s, 1, i - 1) to
                s = substr(s, i + length(from))
            }
            return r s
        }
        { print put(put($0, "@USER@", ENVIRON["OVIS_USER"]), "@PASSWORD@", ENVIRON["OVIS_PASSWORD"]) }
    ' "$template" >"$out/$user.json5"
    chmod 600 "$out/$user.json5"
    echo "wrote $out/$user.json5"
done
