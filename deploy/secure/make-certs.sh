#!/bin/sh
# Certificates for ovis's secure Zenoh profile: a private CA, a router certificate and,
# optionally, client certificates (for mutual TLS).
#
#   deploy/secure/make-certs.sh OUT_DIR [--name HOST]... [--client NAME]... [--days N] [--force]
#
# Writes into OUT_DIR (created, mode 700):
#   ca.crt, ca.key                 the private certificate authority (keep ca.key offline)
#   router.crt, router.key         the router's certificate; its subjectAltName holds
#                                  127.0.0.1, ::1, localhost and every --name (a DNS name
#                                  or an IP address the clients use to reach the router)
#   client-NAME.crt, client-NAME.key   one per --client (CN=NAME), for mutual TLS
#
# Private keys are mode 600. Never commit OUT_DIR (deploy/secure/.gitignore ignores the
# default one, deploy/secure/out/). Existing files are kept unless --force is given, so
# running it again only adds what is missing (e.g. a new --client).
set -eu

usage() {
    sed -n '2,17p' "$0" | sed 's/^# \{0,1\}//' >&2
    exit 2
}

command -v openssl >/dev/null 2>&1 || {
    echo "make-certs.sh: openssl is not installed" >&2
    exit 1
}

[ $# -ge 1 ] || usage
case "$1" in -h | --help | -*) usage ;; esac
out=$1
shift
names=""
clients=""
days=825
force=0
while [ $# -gt 0 ]; do
    case "$1" in
    --name) [ $# -ge 2 ] || usage; names="$names $2"; shift 2 ;;
    --client) [ $# -ge 2 ] || usage; clients="$clients $2"; shift 2 ;;
    --days) [ $# -ge 2 ] || usage; days=$2; shift 2 ;;
    --force) force=1; shift ;;
    *) usage ;;
    esac
done

umask 077
mkdir -p "$out"
chmod 700 "$out"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

fresh() { # true when $1 must be (re)written
    [ "$force" = 1 ] || [ ! -s "$1" ]
}

key() { # an EC P-256 private key, mode 600
    openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1" 2>/dev/null
    chmod 600 "$1"
}

# --- certificate authority -------------------------------------------------------------
if fresh "$out/ca.key" || fresh "$out/ca.crt"; then
    key "$out/ca.key"
    openssl req -x509 -new -key "$out/ca.key" -sha256 -days "$days" \
        -subj "/CN=ovis private CA" \
        -addext "basicConstraints=critical,CA:TRUE" \
        -addext "keyUsage=critical,keyCertSign,cRLSign" \
        -out "$out/ca.crt"
    force=1 # a new CA invalidates every certificate it signed before
    chmod 644 "$out/ca.crt"
    echo "wrote $out/ca.crt (and ca.key: keep it private)"
fi

sign() { # sign NAME CN EXTFILE: NAME.key + NAME.crt signed by the CA
    key "$out/$1.key"
    openssl req -new -key "$out/$1.key" -subj "/CN=$2" -out "$tmp/$1.csr"
    openssl x509 -req -in "$tmp/$1.csr" -CA "$out/ca.crt" -CAkey "$out/ca.key" \
        -CAcreateserial -CAserial "$tmp/ca.srl" -sha256 -days "$days" \
        -extfile "$3" -out "$out/$1.crt" 2>/dev/null
    chmod 644 "$out/$1.crt"
    echo "wrote $out/$1.crt (and $1.key)"
}

is_ip() { # an IPv4 or IPv6 literal
    case "$1" in
    *:*) return 0 ;;
    *[!0-9.]*) return 1 ;;
    *) return 0 ;;
    esac
}

# --- router ------------------------------------------------------------------------------
if fresh "$out/router.key" || fresh "$out/router.crt"; then
    san="IP:127.0.0.1,IP:::1,DNS:localhost"
    for n in $names; do
        if is_ip "$n"; then san="$san,IP:$n"; else san="$san,DNS:$n"; fi
    done
    cat >"$tmp/router.ext" <<EOF
basicConstraints=critical,CA:FALSE
keyUsage=critical,digitalSignature,keyEncipherment
extendedKeyUsage=serverAuth,clientAuth
subjectAltName=$san
EOF
    sign router "ovis router" "$tmp/router.ext"
fi

# --- clients (mutual TLS) ----------------------------------------------------------------
for c in $clients; do
    case "$c" in *[!A-Za-z0-9_.-]*)
        echo "make-certs.sh: client name '$c' must be letters, digits, '_', '.' or '-'" >&2
        exit 2
        ;;
    esac
    if fresh "$out/client-$c.key" || fresh "$out/client-$c.crt"; then
        cat >"$tmp/client.ext" <<EOF
basicConstraints=critical,CA:FALSE
keyUsage=critical,digitalSignature,keyEncipherment
extendedKeyUsage=clientAuth
subjectAltName=DNS:$c
EOF
        sign "client-$c" "$c" "$tmp/client.ext"
    fi
done
