"""The service image's recipe, checked in seconds without building it (``make image`` builds it;
``make image-smoke`` runs it): no secret can reach a layer, the image runs as a non-root user, its
health check needs no token and answers for a real server, the CA bundle reaches the build only as a
build secret, and compose.yaml runs the three roles of the one image on a shared data volume.
"""
from __future__ import annotations

import os
import re
import shlex
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOCKERFILE = REPO / "Dockerfile"
WITH_CA = REPO / "scripts" / "image_with_ca.sh"
ENTRY = REPO / "scripts" / "image_entrypoint.sh"
SECRET_MOUNT = "--mount=type=secret,id=ca-bundle"
SECRET_WORDS = re.compile(r"TOKEN|PASSW|SECRET|PRIVATE|API_?KEY|CREDENTIAL", re.I)


@dataclass(frozen=True)
class Instruction:
    """One Dockerfile instruction: keyword (upper case), its arguments (continuations joined), stage index."""

    keyword: str
    args: str
    stage: int
    line: int


def parse_dockerfile(text: str) -> list[Instruction]:
    """Instructions of a Dockerfile: comments dropped, backslash continuations joined, stages counted."""
    out: list[Instruction] = []
    stage = -1
    buf, start = "", 0
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not buf and (not line or line.startswith("#")):
            continue
        if buf and line.startswith("#"):
            continue
        if not buf:
            start = n
        if line.endswith("\\"):
            buf += line[:-1].rstrip() + " "
            continue
        buf += line
        keyword, _, args = buf.partition(" ")
        keyword = keyword.upper()
        if keyword == "FROM":
            stage += 1
        out.append(Instruction(keyword, args.strip(), stage, start))
        buf = ""
    assert not buf, "Dockerfile ends inside a continued line"
    return out


@pytest.fixture(scope="module")
def instructions() -> list[Instruction]:
    return parse_dockerfile(DOCKERFILE.read_text())


def final_stage(ins: list[Instruction]) -> list[Instruction]:
    last = max(i.stage for i in ins)
    return [i for i in ins if i.stage == last]


def test_parser_joins_continuations_and_counts_stages():
    ins = parse_dockerfile("ARG A=1\nFROM x AS b\n# c\nRUN a \\\n  # inner comment\n  && b\nFROM b\nUSER u\n")
    assert [(i.keyword, i.args, i.stage) for i in ins] == [
        ("ARG", "A=1", -1), ("FROM", "x AS b", 0), ("RUN", "a && b", 0), ("FROM", "b", 1), ("USER", "u", 1)]


def test_final_stage_runs_as_a_non_root_user(instructions):
    users = [i for i in final_stage(instructions) if i.keyword == "USER"]
    assert users, "the final stage has no USER: the image would run as root"
    user = users[-1].args.split(":")[0]
    assert user not in ("root", "0", ""), user
    entry = next(i for i in final_stage(instructions) if i.keyword == "ENTRYPOINT")
    assert users[-1].line < entry.line
    # the user is created with a fixed uid (volumes and certificates can be made readable for it)
    created = [i for i in final_stage(instructions) if i.keyword == "RUN" and "useradd" in i.args]
    assert created and re.search(rf"useradd[^&]*--uid \d+[^&]* {re.escape(user)}\b", created[0].args)


def test_health_check_is_declared_and_needs_no_token(instructions):
    checks = [i for i in final_stage(instructions) if i.keyword == "HEALTHCHECK"]
    assert len(checks) == 1
    assert "CMD" in checks[0].args and "skyloc-role" in checks[0].args and "health" in checks[0].args
    text = ENTRY.read_text()
    health = text[text.index("  health)"):]
    assert "/healthz" in health and "Authorization" not in health and "TOKEN" not in health


def test_ca_bundle_only_through_the_build_secret(instructions):
    uses_ca = [i for i in instructions if i.keyword == "RUN" and "skyloc-with-ca" in i.args
               and not i.args.startswith("chmod")]
    assert uses_ca, "no build step uses the CA helper"
    for i in uses_ca:
        assert i.args.startswith(SECRET_MOUNT), f"line {i.line}: network step without the ca-bundle secret mount"
    for i in instructions:
        if i.keyword in ("COPY", "ADD"):
            assert not re.search(r"\.(pem|crt|key|p12)\b|ca-bundle|/etc/ssl|secrets", i.args), f"line {i.line}: {i.args}"
        if i.keyword in ("ENV", "ARG"):
            assert not re.search(r"PIP_CERT|SSL_CERT|CA_BUNDLE|REQUESTS_CA|CURL_CA", i.args), f"line {i.line}"
        if "/run/secrets" in i.args:
            assert i.keyword == "RUN" and i.args.startswith(SECRET_MOUNT), f"line {i.line}"


def test_no_secret_in_build_args_or_environment(instructions):
    for i in instructions:
        if i.keyword in ("ENV", "ARG", "LABEL"):
            names = re.findall(r"([A-Za-z_][A-Za-z0-9_]*)=", i.args) or [i.args.split()[0]]
            for name in names:
                assert not SECRET_WORDS.search(name), f"line {i.line}: {name} would be stored in the image"


def test_package_indexes_are_build_args_with_public_defaults(instructions):
    args = dict(re.match(r"([A-Z_]+)=?(.*)", i.args).groups() for i in instructions if i.keyword == "ARG")
    assert args["PIP_INDEX_URL"] == "https://pypi.org/simple"
    assert args["APT_MIRROR"] == "http://deb.debian.org/debian"
    assert args["APT_SECURITY_MIRROR"] == "http://deb.debian.org/debian-security"
    assert args["BASE_IMAGE"] == "debian:bookworm-slim"
    assert "PIP_EXTRA_INDEX_URL" in args


def test_multi_stage_runtime_has_no_compilers_and_no_bpy(instructions):
    assert max(i.stage for i in instructions) >= 1
    runtime_runs = " ".join(i.args for i in final_stage(instructions) if i.keyword == "RUN")
    for pkg in ("build-essential", "-dev", "gcc"):
        assert pkg not in runtime_runs
    extras = next(i.args for i in instructions if i.keyword == "ARG" and i.args.startswith("SKYLOC_EXTRAS="))
    assert "blender" not in extras  # the image serves the raymarch renderer; bpy is not installed
    copies = [i.args for i in final_stage(instructions) if i.keyword == "COPY"]
    assert any(c.startswith("--from=builder /opt/skyloc") for c in copies)


def test_dockerignore_keeps_credentials_and_environments_out_of_the_context():
    patterns = [p.strip() for p in (REPO / ".dockerignore").read_text().splitlines() if p.strip() and p[0] != "#"]
    for need in (".git", ".venv", "**/*.pem", "**/*.key", "**/.env", "**/.netrc"):
        assert need in patterns, need
    # the context still holds what the Dockerfile copies
    for i in parse_dockerfile(DOCKERFILE.read_text()):
        if i.keyword == "COPY" and not i.args.startswith("--from"):
            for src in shlex.split(i.args)[:-1]:
                assert (REPO / src).exists(), src
                assert src not in patterns, src


def run_with_ca(tmp_path: Path, secret: str | None, command: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "SKYLOC_CA_SECRET": str(tmp_path / "secret"), "SKYLOC_SYSTEM_CA": str(tmp_path / "system.pem"),
           "SKYLOC_APT_CA_CONF": str(tmp_path / "apt.conf"), "TMPDIR": str(tmp_path / "tmp")}
    (tmp_path / "tmp").mkdir(exist_ok=True)
    (tmp_path / "system.pem").write_text("SYSTEM-CA\n")
    if secret is not None:
        (tmp_path / "secret").write_text(secret)
    return subprocess.run(["sh", str(WITH_CA), "sh", "-c", command], env=env, capture_output=True, text=True)


def test_ca_helper_trusts_system_plus_secret_during_the_command_and_leaves_nothing(tmp_path):
    cmd = 'cat "$PIP_CERT"; echo ---; cat "$SKYLOC_APT_CA_CONF"; echo ---; echo "$SSL_CERT_FILE $REQUESTS_CA_BUNDLE"'
    r = run_with_ca(tmp_path, "PROXY-CA\n", cmd)
    assert r.returncode == 0, r.stderr
    bundle, apt, env_line = r.stdout.split("---\n")
    assert bundle == "SYSTEM-CA\nPROXY-CA\n"
    path = re.search(r'CAInfo "([^"]+)"', apt).group(1)
    assert env_line.split() == [path, path]
    assert not Path(path).exists() and not (tmp_path / "apt.conf").exists()
    assert list((tmp_path / "tmp").iterdir()) == []  # the combined bundle is gone when the RUN ends
    failed = run_with_ca(tmp_path, "PROXY-CA\n", "exit 7")  # a failing step cleans up too, status kept
    assert failed.returncode == 7 and list((tmp_path / "tmp").iterdir()) == [] and not (tmp_path / "apt.conf").exists()


def test_ca_helper_without_the_secret_changes_nothing(tmp_path):
    r = run_with_ca(tmp_path, None, 'echo "${PIP_CERT-unset}"; test ! -e "$SKYLOC_APT_CA_CONF"')
    assert r.returncode == 0 and r.stdout.strip() == os.environ.get("PIP_CERT", "unset")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("role", ["scheduler", "worker"])
def test_dask_roles_refuse_to_run_without_tls(role, tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("SKYLOC_", "DASK_"))}
    env.update(SKYLOC_SCHEDULER="tcp://127.0.0.1:1", SKYLOC_ROLE_FILE=str(tmp_path / "role"))
    r = subprocess.run(["sh", str(ENTRY), role], env=env, capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "without TLS" in r.stderr and "skyloc-role tls DIR" in r.stderr, r.stderr
    assert not (tmp_path / "role").exists()  # refused before anything started
    env["SKYLOC_TLS_CA_FILE"] = str(tmp_path / "missing.pem")
    env.update(SKYLOC_TLS_CERT=str(tmp_path / "missing.pem"), SKYLOC_TLS_KEY=str(tmp_path / "missing.pem"))
    r = subprocess.run(["sh", str(ENTRY), role], env=env, capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "cannot read" in r.stderr and "missing.pem" in r.stderr, r.stderr


@pytest.mark.service
def test_health_check_passes_for_a_tokened_api_and_fails_when_it_is_down(tmp_path):
    """The HEALTHCHECK command against a real `api` role (API only, no cluster) started with a token."""
    port = _free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("SKYLOC_", "DASK_"))}
    env.update(PATH=f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}", PYTHONPATH=str(REPO),
               SKYLOC_BIND_HOST="127.0.0.1", SKYLOC_PORT=str(port), SKYLOC_DATA_DIR=str(tmp_path / "data"),
               SKYLOC_TOKEN="health-check-token-0123456789", SKYLOC_START_CLUSTER="false",
               SKYLOC_ROLE_FILE=str(tmp_path / "role"))
    health = ["sh", str(ENTRY), "health"]
    assert subprocess.run(health, env=env, capture_output=True).returncode != 0  # no role started yet
    proc = subprocess.Popen(["sh", str(ENTRY), "api", "--log-level", "warning"], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        t_end = time.monotonic() + 60
        while (r := subprocess.run(health, env=env, capture_output=True)).returncode != 0:
            assert proc.poll() is None and time.monotonic() < t_end, r.stderr
            time.sleep(0.3)
        assert (tmp_path / "role").read_text().strip() == "api"
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(20)
    assert subprocess.run(health, env=env, capture_output=True).returncode != 0  # server gone: unhealthy


def test_compose_runs_the_three_roles_of_one_image_on_a_shared_volume():
    yaml = pytest.importorskip("yaml")
    doc = yaml.safe_load((REPO / "compose.yaml").read_text())
    services = doc["services"]
    assert {"api", "scheduler", "worker"} <= set(services)
    images = {s.get("image") for s in services.values()}
    assert len(images) == 1 and None not in images
    roles = {name: (s.get("command") or ["api"])[0] for name, s in services.items()}
    assert roles["api"] == "api" and roles["scheduler"] == "scheduler" and roles["worker"] == "worker"

    def mounts(svc: dict) -> dict[str, str]:
        out = {}
        for v in svc.get("volumes", []):
            src, dst = (v["source"], v["target"]) if isinstance(v, dict) else v.split(":")[:2]
            out[dst] = src
        return out

    assert mounts(services["api"])["/data"] == mounts(services["worker"])["/data"]  # same data, same path
    for name, svc in services.items():
        env = svc.get("environment", {})
        env = dict(e.split("=", 1) for e in env) if isinstance(env, list) else env
        for key, value in env.items():
            if SECRET_WORDS.search(key):
                assert value is None or str(value).startswith("${") or "FILE" in key, f"{name}: {key} in clear"
        if name in ("api", "scheduler", "worker"):
            assert env.get("SKYLOC_SCHEDULER", "tls://").startswith("tls://"), name
            assert "SKYLOC_TLS_CA_FILE" in env, f"{name}: Dask traffic without TLS"
