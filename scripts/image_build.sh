#!/usr/bin/env bash
# Builds the render-service image (Dockerfile) with whatever engine this machine has:
# docker (a running daemon), podman, or buildah (storage driver vfs, --isolation chroot: works as root
# with no daemon).  With buildah, when debian:bookworm-slim cannot be pulled, the base is made here by
# `debootstrap --variant=minbase bookworm` and imported as localhost/skyloc-base:bookworm.
#
# Behind a TLS-inspecting proxy, the proxy's certificate authority is passed as the build secret
# `ca-bundle` (used by apt and pip during the build only, never stored in a layer).
#
# Environment (all optional):
#   IMAGE            image name                             [skyloc-service:latest]
#   ENGINE           docker | podman | buildah | auto         [auto: the first that works]
#   CA_BUNDLE        extra CA bundle for the build            [$PIP_CERT, else $SSL_CERT_FILE, else none]
#   PIP_INDEX_URL, PIP_EXTRA_INDEX_URL, APT_MIRROR, APT_SECURITY_MIRROR
#                    package indexes (build args; http(s) only; public defaults in the Dockerfile)
#   BASE_IMAGE       base image                              [debian:bookworm-slim]
#   BUILD_NICE       niceness of the build                   [15]
#   STORAGE_DRIVER   buildah's storage driver                 [vfs]
#   DEBOOTSTRAP_MIRROR  mirror for the debootstrap base      [$APT_MIRROR, else http://deb.debian.org/debian]
#   IMAGE_CONTEXT    "." (the working tree) or "git" (the committed HEAD only, as a clean clone has it)  [.]
set -euo pipefail
cd "$(dirname "$0")/.."

IMAGE=${IMAGE:-skyloc-service:latest}
ENGINE=${ENGINE:-auto}
BASE_IMAGE=${BASE_IMAGE:-debian:bookworm-slim}
NICE=${BUILD_NICE:-15}
CA_BUNDLE=${CA_BUNDLE-${PIP_CERT:-${SSL_CERT_FILE:-}}}
WORK=${IMAGE_WORK_DIR:-/var/tmp/skyloc-image}
STORAGE_DRIVER=${STORAGE_DRIVER:-vfs}   # buildah's storage; vfs works everywhere (overlay may not, nested)
buildah() { command buildah --storage-driver "$STORAGE_DRIVER" "$@"; }
LOCAL_BASE=localhost/skyloc-base:bookworm

say() { echo "image_build: $*" >&2; }
die() { say "error: $*"; exit 1; }

pick_engine() {
  if [ "$ENGINE" != auto ]; then
    type -P "$ENGINE" >/dev/null 2>&1 || die "ENGINE=$ENGINE is not installed"
    echo "$ENGINE"; return
  fi
  # a docker client without a daemon (common in sandboxes) does not count
  if command -v docker >/dev/null 2>&1 && docker info >/dev/null 2>&1; then echo docker; return; fi
  if command -v podman >/dev/null 2>&1 && podman info >/dev/null 2>&1; then echo podman; return; fi
  if ! type -P buildah >/dev/null 2>&1 && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    say "no container engine: apt-get install buildah debootstrap"
    { apt-get update -qq && DEBIAN_FRONTEND=noninteractive nice -n "$NICE" apt-get install -y -qq buildah debootstrap; } >&2 \
      || die "apt-get install buildah debootstrap failed"
  fi
  if type -P buildah >/dev/null 2>&1; then echo buildah; return; fi
  die "no container engine: install one (as root on Debian 12: apt-get install -y buildah debootstrap)"
}

# Build args for the package indexes: only http(s) URLs are passed (a host's file:// index means nothing
# inside the build); the Dockerfile's defaults are the public indexes.
build_args=()
for var in PIP_INDEX_URL PIP_EXTRA_INDEX_URL APT_MIRROR APT_SECURITY_MIRROR; do
  val=${!var:-}
  case "$val" in
    http://*|https://*) build_args+=(--build-arg "$var=$val") ;;
    "") ;;
    *) say "ignoring $var=$val (not an http(s) URL; the build uses the Dockerfile's default)" ;;
  esac
done

secret_args=()
if [ -n "$CA_BUNDLE" ]; then
  [ -r "$CA_BUNDLE" ] || die "CA_BUNDLE=$CA_BUNDLE is not a readable file (unset it to build without an extra CA)"
  secret_args=(--secret "id=ca-bundle,src=$CA_BUNDLE")
  say "extra CA bundle for the build: $CA_BUNDLE (build secret, not stored in the image)"
fi

# buildah: the base image, pulled or made by debootstrap (minbase, slimmed like debian:*-slim)
debootstrap_base() {
  command -v debootstrap >/dev/null 2>&1 || die "cannot pull $BASE_IMAGE and debootstrap is missing: apt-get install -y debootstrap"
  [ "$(id -u)" = 0 ] || die "debootstrap needs root"
  local mirror=${DEBOOTSTRAP_MIRROR:-${APT_MIRROR:-http://deb.debian.org/debian}}
  local rootfs=$WORK/rootfs
  rm -rf "$rootfs"; mkdir -p "$WORK"
  say "debootstrap --variant=minbase bookworm from $mirror"
  nice -n "$NICE" debootstrap --variant=minbase bookworm "$rootfs" "$mirror" >"$WORK/debootstrap.log" 2>&1 \
    || die "debootstrap failed (log: $WORK/debootstrap.log)"
  # what debian:bookworm-slim does: no docs, man pages or locales from later installs; no apt caches
  cat >"$rootfs/etc/dpkg/dpkg.cfg.d/docker" <<'EOF'
path-exclude /usr/share/doc/*
path-include /usr/share/doc/*/copyright
path-exclude /usr/share/man/*
path-exclude /usr/share/info/*
path-exclude /usr/share/locale/*
path-include /usr/share/locale/locale.alias
EOF
  echo 'APT::Install-Recommends "false";' >"$rootfs/etc/apt/apt.conf.d/docker-no-recommends"
  find "$rootfs/usr/share/doc" -mindepth 1 -not -name copyright -not -type d -delete 2>/dev/null || true
  find "$rootfs/usr/share/locale" -mindepth 1 -maxdepth 1 -not -name locale.alias -exec rm -rf {} + 2>/dev/null || true
  rm -rf "$rootfs"/usr/share/man/* "$rootfs"/usr/share/info/* "$rootfs"/var/lib/apt/lists/* \
         "$rootfs"/var/cache/apt/*.bin "$rootfs"/var/cache/apt/archives/*.deb "$rootfs"/var/log/*.log
  local ctr mnt
  ctr=$(buildah from scratch)
  mnt=$(buildah mount "$ctr")
  tar -C "$rootfs" --numeric-owner -cf - . | tar -C "$mnt" --numeric-owner -xpf -
  buildah umount "$ctr" >/dev/null
  buildah config --env PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin --cmd /bin/bash \
    --label org.opencontainers.image.description="debootstrap --variant=minbase bookworm (skyloc image base)" "$ctr"
  buildah commit --rm "$ctr" "$LOCAL_BASE" >/dev/null
  rm -rf "$rootfs"
  say "base image $LOCAL_BASE made by debootstrap"
}

CONTEXT=.
if [ "${IMAGE_CONTEXT:-.}" = git ]; then
  CONTEXT=$WORK/context
  rm -rf "$CONTEXT"; mkdir -p "$CONTEXT"
  git archive --format=tar HEAD | tar -C "$CONTEXT" -xf -
  say "context: git HEAD $(git rev-parse --short HEAD) (uncommitted changes left out)"
fi

engine=$(pick_engine)
say "engine: $engine, image: $IMAGE"
t0=$(date +%s)
case "$engine" in
  docker)
    DOCKER_BUILDKIT=1 nice -n "$NICE" docker build -t "$IMAGE" --build-arg "BASE_IMAGE=$BASE_IMAGE" \
      "${build_args[@]}" "${secret_args[@]}" "$CONTEXT"
    ;;
  podman)
    nice -n "$NICE" podman build --format docker -t "$IMAGE" --build-arg "BASE_IMAGE=$BASE_IMAGE" \
      "${build_args[@]}" "${secret_args[@]}" "$CONTEXT"
    ;;
  buildah)
    base=$BASE_IMAGE
    if ! buildah inspect --type image "$base" >/dev/null 2>&1; then
      if timeout 120 "$(type -P buildah)" --storage-driver "$STORAGE_DRIVER" pull --quiet "$base" >/dev/null 2>&1; then
        say "pulled $base"
      elif buildah inspect --type image "$LOCAL_BASE" >/dev/null 2>&1 && [ "${REBUILD_BASE:-0}" != 1 ]; then
        say "cannot pull $base: using the debootstrap base $LOCAL_BASE made earlier (REBUILD_BASE=1 remakes it)"
        base=$LOCAL_BASE
      else
        say "cannot pull $base: making the base with debootstrap"
        debootstrap_base
        base=$LOCAL_BASE
      fi
    fi
    # --format docker keeps HEALTHCHECK (the OCI image format has no field for it)
    nice -n "$NICE" "$(type -P buildah)" --storage-driver "$STORAGE_DRIVER" bud --isolation chroot --format docker --layers --pull-never -t "$IMAGE" \
      --build-arg "BASE_IMAGE=$base" "${build_args[@]}" "${secret_args[@]}" "$CONTEXT"
    ;;
esac
t1=$(date +%s)
say "built $IMAGE in $((t1 - t0)) s"
case "$engine" in
  buildah) buildah images --format '{{.Name}}:{{.Tag}} {{.Size}}' | grep -F "${IMAGE%%:*}" >&2 || true ;;
  *) "$engine" image ls "$IMAGE" >&2 || true ;;
esac
