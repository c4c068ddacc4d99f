#!/bin/sh
# Build-time helper of the Dockerfile (installed as /usr/local/bin/skyloc-with-ca): runs a command
# with the optional extra CA bundle of the build secret `ca-bundle` trusted by apt, pip and curl.
#
#   RUN --mount=type=secret,id=ca-bundle skyloc-with-ca apt-get update
#
# When /run/secrets/ca-bundle is present and not empty, the trust store for the command is the
# system bundle (when ca-certificates is installed) followed by the secret, written to a temporary
# file that is deleted when the command ends, inside the same RUN: no layer ever holds it.
# Without the secret the command runs unchanged (a build with no TLS-inspecting proxy).
set -eu
SECRET=${SKYLOC_CA_SECRET:-/run/secrets/ca-bundle}   # overridable for the tests only
SYSTEM_CA=${SKYLOC_SYSTEM_CA:-/etc/ssl/certs/ca-certificates.crt}
if [ ! -s "$SECRET" ]; then
  exec "$@"
fi
tmp=$(mktemp -d "${TMPDIR:-/tmp}/skyloc-ca.XXXXXX")
apt_conf=${SKYLOC_APT_CA_CONF:-/etc/apt/apt.conf.d/99skyloc-build-ca}
cleanup() { rm -rf "$tmp" "$apt_conf"; }
trap cleanup EXIT INT TERM
if [ -s "$SYSTEM_CA" ]; then
  cat "$SYSTEM_CA" "$SECRET" >"$tmp/ca.pem"
else
  cat "$SECRET" >"$tmp/ca.pem"
fi
echo "Acquire::https::CAInfo \"$tmp/ca.pem\";" >"$apt_conf"
PIP_CERT="$tmp/ca.pem" SSL_CERT_FILE="$tmp/ca.pem" REQUESTS_CA_BUNDLE="$tmp/ca.pem" CURL_CA_BUNDLE="$tmp/ca.pem" \
  "$@"
