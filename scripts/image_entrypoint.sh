#!/bin/sh
# Entry point of the render-service image (installed as /usr/local/bin/skyloc-role, run under tini).
# One image, three roles, chosen by the first argument:
#
#   api        skyloc serve on 0.0.0.0:$SKYLOC_PORT (8000) with data in $SKYLOC_DATA_DIR (/data);
#              a LocalCluster unless SKYLOC_SCHEDULER (tls://scheduler:8786) names a scheduler.
#              Needs SKYLOC_TOKEN or --token-file (it refuses a non-loopback interface without one).
#   scheduler  dask scheduler on 0.0.0.0:$SKYLOC_DASK_PORT (8786), no dashboard
#   worker     dask worker connecting to $SKYLOC_SCHEDULER, one thread per process
#              ($SKYLOC_WORKER_PROCESSES processes, default 1), no dashboard
#   tls DIR    make a CA and a node certificate + key for Dask TLS in DIR (openssl)
#   health     the image's HEALTHCHECK for whichever role this container runs (no token needed)
#   anything else is run as a command (skyloc db render ..., dask ..., bash)
#
# SKYLOC_BIND_HOST (0.0.0.0) is the interface of the api and scheduler roles.
#
# Dask TLS for every role (and for the API server's client): mount a folder with the CA certificate
# and this node's certificate + key, and set SKYLOC_TLS_CA_FILE, SKYLOC_TLS_CERT, SKYLOC_TLS_KEY.
# They become Dask's own configuration (DASK_DISTRIBUTED__COMM__TLS__*, require-encryption on), so
# a connection without a certificate signed by that CA is refused.  Extra arguments after the role
# are passed to skyloc serve / dask scheduler / dask worker.
set -eu

ROLE=${1:-api}
[ $# -gt 0 ] && shift
ROLE_FILE=${SKYLOC_ROLE_FILE:-/tmp/skyloc-role}   # which role this container runs (for `health`)
BIND=${SKYLOC_BIND_HOST:-0.0.0.0}

tls_env() {
  if [ -n "${SKYLOC_TLS_CA_FILE:-}" ]; then
    for f in "$SKYLOC_TLS_CA_FILE" "${SKYLOC_TLS_CERT:?SKYLOC_TLS_CERT must name this node's certificate}" \
             "${SKYLOC_TLS_KEY:?SKYLOC_TLS_KEY must name this node's private key}"; do
      [ -r "$f" ] || { echo "skyloc-role: cannot read $f (mount the certificates readable by uid $(id -u))" >&2; exit 2; }
    done
    export DASK_DISTRIBUTED__COMM__REQUIRE_ENCRYPTION=True
    export DASK_DISTRIBUTED__COMM__TLS__CA_FILE="$SKYLOC_TLS_CA_FILE"
    for who in SCHEDULER WORKER CLIENT; do
      export "DASK_DISTRIBUTED__COMM__TLS__${who}__CERT=$SKYLOC_TLS_CERT"
      export "DASK_DISTRIBUTED__COMM__TLS__${who}__KEY=$SKYLOC_TLS_KEY"
    done
    PROTO=tls
  else
    PROTO=tcp
  fi
}

# A plain-TCP Dask scheduler or worker lets anyone who reaches it run code as this user: refused
# unless asked for (SKYLOC_DASK_INSECURE=1, e.g. on a private test network).
require_tls() {
  if [ "$PROTO" != tls ] && [ "${SKYLOC_DASK_INSECURE:-0}" != 1 ]; then
    echo "skyloc-role: refusing to run a Dask $ROLE without TLS: set SKYLOC_TLS_CA_FILE, SKYLOC_TLS_CERT and" \
         "SKYLOC_TLS_KEY (make them with: skyloc-role tls DIR), or SKYLOC_DASK_INSECURE=1 to accept plain TCP" >&2
    exit 2
  fi
}

case "$ROLE" in
  api)
    tls_env
    echo api >"$ROLE_FILE"
    exec skyloc serve --host "$BIND" --port "${SKYLOC_PORT:-8000}" --data "${SKYLOC_DATA_DIR:-/data}" "$@"
    ;;
  scheduler)
    tls_env
    require_tls
    echo scheduler >"$ROLE_FILE"
    exec dask scheduler --protocol "$PROTO" --host "$BIND" --port "${SKYLOC_DASK_PORT:-8786}" --no-dashboard "$@"
    ;;
  worker)
    tls_env
    require_tls
    : "${SKYLOC_SCHEDULER:?SKYLOC_SCHEDULER must name the scheduler, e.g. tls://scheduler:8786}"
    echo worker >"$ROLE_FILE"
    exec dask worker "$SKYLOC_SCHEDULER" --nthreads 1 --nworkers "${SKYLOC_WORKER_PROCESSES:-1}" \
      --no-dashboard --local-directory "${SKYLOC_WORKER_DIR:-/tmp/dask-worker}" "$@"
    ;;
  tls)
    # skyloc-role tls DIR [NAME...]: a CA and one node certificate (for NAMEs, default the compose
    # service names) in DIR; as root the files are handed to the image user (uid 10001), key mode 0600.
    out=${1:?usage: skyloc-role tls DIR [NAME...]}
    [ $# -gt 0 ] && shift
    [ $# -gt 0 ] || set -- scheduler worker api localhost
    [ -e "$out/ca.pem" ] && { echo "skyloc-role: $out/ca.pem exists; remove $out to make new certificates" >&2; exit 2; }
    mkdir -p "$out"
    umask 077
    san="IP:127.0.0.1"
    for n in "$@"; do san="$san,DNS:$n"; done
    printf 'subjectAltName=%s\nextendedKeyUsage=serverAuth,clientAuth\n' "$san" >"$out/node.ext"
    openssl req -x509 -newkey rsa:2048 -nodes -keyout "$out/ca.key" -out "$out/ca.pem" -days "${SKYLOC_TLS_DAYS:-825}" \
      -subj "/CN=skyloc deployment CA" 2>/dev/null
    openssl req -newkey rsa:2048 -nodes -keyout "$out/node.key" -out "$out/node.csr" -subj "/CN=skyloc-node" 2>/dev/null
    openssl x509 -req -in "$out/node.csr" -CA "$out/ca.pem" -CAkey "$out/ca.key" -CAcreateserial \
      -out "$out/node.pem" -days "${SKYLOC_TLS_DAYS:-825}" -extfile "$out/node.ext" 2>/dev/null
    rm -f "$out/node.csr" "$out/node.ext" "$out/ca.srl"
    chmod 0644 "$out/ca.pem" "$out/node.pem"
    [ "$(id -u)" = 0 ] && chown -R "${SKYLOC_TLS_OWNER:-10001:10001}" "$out"
    echo "skyloc-role: wrote $out/{ca.pem,ca.key,node.pem,node.key} (keep ca.key offline; nodes need the other three)" >&2
    exit 0
    ;;
  health)
    exec python - "$(cat "$ROLE_FILE" 2>/dev/null || echo none)" <<'EOF'
import os, socket, sys, urllib.request
role = sys.argv[1]
if role == "api":  # /healthz needs no token; "degraded" (Dask unreachable) still answers 200
    port = os.environ.get("SKYLOC_PORT", "8000")
    urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=4).read()
elif role == "scheduler":
    socket.create_connection(("127.0.0.1", int(os.environ.get("SKYLOC_DASK_PORT", "8786"))), timeout=4).close()
elif role == "worker":  # alive while connected to its scheduler
    addr = os.environ["SKYLOC_SCHEDULER"].split("://")[-1]
    host, _, port = addr.rpartition(":")
    socket.create_connection((host, int(port)), timeout=4).close()
else:
    sys.exit(f"no role started in this container ({role})")
EOF
    ;;
  *)
    tls_env
    exec "$ROLE" "$@"
    ;;
esac
