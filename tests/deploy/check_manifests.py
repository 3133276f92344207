#!/usr/bin/env python3
"""Checks the deployment files of TwistSLAM for the essentials.

    python3 tests/deploy/check_manifests.py [--root REPO] [--self-test]

What is checked (each failure is one line naming the file and the problem):
  * YAML lint (yamllint with tests/deploy/yamllint.yaml) of deploy/compose.yaml
    and every file under deploy/k8s/, when yamllint is installed;
  * deploy/Dockerfile: ARG BASE before the first FROM and used by FROM, the
    build stage runs deploy/install-deps.sh, tests and benchmarks off, a
    non-root USER, the state VOLUME, EXPOSE = the ENTRYPOINT's listen port,
    a HEALTHCHECK with the project's health probe on that port, and the
    config file it copies exists;
  * deploy/compose.yaml: the server's state volume, health check, stop grace
    above the drain deadline, and a client job that waits for a healthy server
    and streams to it on the server's port;
  * deploy/k8s (rendered like `kustomize build`: resources, the ConfigMap
    generator and, for each overlay, its JSON patches): a StatefulSet behind a
    headless Service with matching selectors and ports; startup, readiness and
    liveness probes asking grpc.health.v1 on the gRPC port (exec probes with
    the project's probe over TLS when the server runs TLS, since the built-in
    `grpc:` probe cannot); every file the server and probes read lies on a
    mounted volume; the state dir is a PersistentVolumeClaim template;
    terminationGracePeriodSeconds >= the server's shutdown bound (drain +
    deadline + 5 s, server/main.cc);
    CPU and memory requests and limits; a PodDisruptionBudget that selects the
    pods and allows one eviction; non-root security context;
  * the server configs (deploy/config/server.yaml in the image,
    deploy/k8s/config/server.yaml in the ConfigMap) parse as the server reads
    them and give its shutdown deadline.

--self-test breaks the rendered manifests in known ways in memory and checks
that each breakage is reported (so the checks themselves can fail).

Exit codes: 0 all good, 1 problems found, 77 skipped (python3-yaml missing;
ctest reports a skip).
"""

import argparse
import copy
import json
import os
import re
import shlex
import shutil
import subprocess
import sys

try:
    import yaml
except ImportError:  # pragma: no cover - depends on the machine
    print("SKIP: python3-yaml is not installed (apt-get install python3-yaml)")
    sys.exit(77)

PROBE_BINARY = "twistslam-health-probe"
SERVER_BINARY = "twistslam-server"


class Problems:
    def __init__(self):
        self.items = []

    def add(self, where, what):
        self.items.append(f"{where}: {what}")

    def check(self, condition, where, what):
        if not condition:
            self.add(where, what)
        return condition


# ---------------------------------------------------------------------------
# Server config


def parse_duration_s(value):
    """A number of seconds, or a string such as '30s', '2m', '1500ms'."""
    if isinstance(value, bool):
        raise ValueError(f"not a duration: {value!r}")
    if isinstance(value, (int, float)):
        return float(value)
    m = re.fullmatch(r"\s*([0-9]+(?:\.[0-9]*)?)\s*(ms|s|m|h)?\s*", str(value))
    if not m:
        raise ValueError(f"not a duration: {value!r}")
    number = float(m.group(1))
    return number * {"ms": 0.001, "s": 1, "m": 60, "h": 3600, None: 1}[m.group(2)]


# The server's shutdown settings (server/server_flags.cc) and their defaults.
# On SIGTERM it drains streams for up to drain_timeout_s, persists every
# session, and ends the remaining calls by shutdown_deadline_s; server/main.cc
# exits at the latest after drain_timeout_s + shutdown_deadline_s + 5 s (its
# outer bound). The orchestrator's grace period must cover that bound, or
# SIGKILL can cut the persisting short.
SHUTDOWN_OUTER_MARGIN_S = 5.0
SHUTDOWN_DEFAULTS = {"drain_timeout_s": 5.0, "shutdown_deadline_s": 10.0}


def parse_config_text(text):
    """Top-level `key: value` settings of a server config, which is YAML as
    OpenCV's cv::FileStorage reads it (a `%YAML:1.0` first line, `---`, '#'
    comments, nested maps such as `slam:` indented) or JSON."""
    stripped = text.strip()
    if stripped.startswith("{"):
        return json.loads(stripped)
    lines = text.splitlines()
    if not lines or not lines[0].startswith("%YAML"):
        raise ValueError("the first line must be %YAML:1.0 (cv::FileStorage needs it)")
    values = {}
    for number, raw in enumerate(lines[1:], 2):
        line = raw.split("#", 1)[0].rstrip()
        if not line.strip() or line.strip() == "---" or line[0] in " \t":
            continue  # blank, document start, or inside a nested map
        m = re.fullmatch(r"([A-Za-z_][A-Za-z0-9_]*)\s*:\s*(.*)", line)
        if not m:
            raise ValueError(f"line {number}: expected 'key: value': {raw!r}")
        if "-" in m.group(1):
            raise ValueError(f"line {number}: keys use '_' for '-'")
        values[m.group(1)] = m.group(2).strip().strip('"')
    return values


def settings_bound_s(values):
    """The server's outer shutdown bound for the given config values."""
    settings = {k: parse_duration_s(values.get(k, d)) for k, d in SHUTDOWN_DEFAULTS.items()}
    return settings, settings["drain_timeout_s"] + settings["shutdown_deadline_s"] + \
        SHUTDOWN_OUTER_MARGIN_S


def shutdown_deadline_s(config_path, problems):
    """Seconds the server may take to exit after SIGTERM, from the config and
    the server's defaults (drain + deadline + its 5 s outer margin)."""
    where = os.path.relpath(config_path)
    try:
        with open(config_path, encoding="utf-8") as f:
            values = parse_config_text(f.read())
        settings, bound = settings_bound_s(values)
    except (OSError, ValueError) as e:
        problems.add(where, f"cannot read server config: {e}")
        return None
    problems.check(settings["shutdown_deadline_s"] > 0, where, "shutdown_deadline_s must be > 0")
    problems.check(settings["drain_timeout_s"] <= settings["shutdown_deadline_s"], where,
                   "drain_timeout_s above shutdown_deadline_s leaves no time to persist")
    return bound


# ---------------------------------------------------------------------------
# Command lines


def flag_value(args, flag):
    """Value of `--flag value` or `--flag=value` in an argv list, else None."""
    for i, arg in enumerate(args):
        if arg == flag and i + 1 < len(args):
            return args[i + 1]
        if arg.startswith(flag + "="):
            return arg[len(flag) + 1:]
    return None


def port_of(addr):
    m = re.fullmatch(r"\[?[^\]]*\]?:([0-9]+)", addr or "")
    return int(m.group(1)) if m else None


def under_mount(path, mount_paths):
    return any(path == m or path.startswith(m.rstrip("/") + "/") for m in mount_paths)


# ---------------------------------------------------------------------------
# Dockerfile


def dockerfile_instructions(text):
    """(instruction, arguments) pairs with line continuations joined."""
    joined = re.sub(r"\\\n", " ", text)
    out = []
    for line in joined.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split(None, 1)
        out.append((parts[0].upper(), parts[1] if len(parts) > 1 else ""))
    return out


def exec_form(args):
    args = args.strip()
    if args.startswith("["):
        return json.loads(args)
    return shlex.split(args)


def check_dockerfile(root, problems):
    path = os.path.join(root, "deploy/Dockerfile")
    where = "deploy/Dockerfile"
    try:
        with open(path, encoding="utf-8") as f:
            instructions = dockerfile_instructions(f.read())
    except OSError as e:
        problems.add(where, str(e))
        return {}
    names = [i for i, _ in instructions]
    first_from = names.index("FROM") if "FROM" in names else -1
    problems.check(first_from >= 0, where, "no FROM")
    problems.check(any(i == "ARG" and a.split("=")[0].strip() == "BASE"
                       for i, a in instructions[:max(first_from, 0)]),
                   where, "ARG BASE must come before the first FROM")
    froms = [a for i, a in instructions if i == "FROM"]
    problems.check(len(froms) >= 2, where, "not multi-stage")
    stages = []
    for a in froms:
        words = a.split()
        image = [w for w in words if not w.startswith("--")][0]
        problems.check(image in ("${BASE}", "$BASE") or image in stages, where,
                       f"FROM {image}: every stage must start from ${{BASE}} or an earlier stage")
        if len(words) >= 3 and words[-2].upper() == "AS":
            stages.append(words[-1])
    problems.check(any("${BASE}" in a for a in froms), where, "no stage uses ${BASE}")
    runs = " ".join(a for i, a in instructions if i == "RUN")
    problems.check("deploy/install-deps.sh" in " ".join(a for i, a in instructions if i == "COPY")
                   and "install-deps.sh" in runs,
                   where, "the build stage must run deploy/install-deps.sh")
    problems.check("-DTWIST_BUILD_TESTS=OFF" in runs and "-DTWIST_BUILD_BENCH=OFF" in runs,
                   where, "build with -DTWIST_BUILD_TESTS=OFF -DTWIST_BUILD_BENCH=OFF")
    problems.check("cmake --install" in runs, where, "no cmake --install")

    # Everything after the last FROM is the runtime stage.
    last_from = max(i for i, (n, _) in enumerate(instructions) if n == "FROM")
    runtime = instructions[last_from:]
    users = [a.strip() for i, a in runtime if i == "USER"]
    problems.check(users and users[-1].split(":")[0] not in ("root", "0"),
                   where, "the runtime stage must run as a non-root USER")
    volumes = [a for i, a in runtime if i == "VOLUME"]
    problems.check(any("/var/lib/twistslam" in v for v in volumes), where,
                   "VOLUME /var/lib/twistslam missing")
    entry = [a for i, a in runtime if i == "ENTRYPOINT"]
    info = {"user": users[-1] if users else None}
    if problems.check(entry, where, "no ENTRYPOINT"):
        argv = exec_form(entry[-1])
        info["entrypoint"] = argv
        problems.check(argv and argv[0].endswith(SERVER_BINARY), where,
                       "ENTRYPOINT must start twistslam-server")
        port = port_of(flag_value(argv, "--listen"))
        info["port"] = port
        problems.check(port, where, "ENTRYPOINT needs --listen HOST:PORT")
        problems.check(flag_value(argv, "--state-dir") == "/var/lib/twistslam", where,
                       "ENTRYPOINT must use --state-dir /var/lib/twistslam")
        exposed = [int(p.split("/")[0]) for i, a in runtime if i == "EXPOSE" for p in a.split()]
        problems.check(port in exposed, where, f"EXPOSE {port} missing (listen port)")
        checks = [a for i, a in runtime if i == "HEALTHCHECK"]
        if problems.check(checks, where, "no HEALTHCHECK"):
            m = re.search(r"\bCMD\s+(.*)$", checks[-1])
            probe = exec_form(m.group(1)) if m else []
            problems.check(probe and probe[0].endswith(PROBE_BINARY), where,
                           "HEALTHCHECK must run twistslam-health-probe")
            problems.check(port_of(flag_value(probe, "--addr")) == port, where,
                           "HEALTHCHECK probe must ask the listen port")
        config = flag_value(argv, "--config")
        if config:
            copies = [a.split() for i, a in runtime if i == "COPY" and not a.startswith("--from")]
            sources = [c[0] for c in copies if c and c[-1] == config]
            if problems.check(sources, where, f"--config {config} is not copied into the image"):
                info["config"] = os.path.join(root, sources[0])
                problems.check(os.path.isfile(info["config"]), where,
                               f"{sources[0]} does not exist")
    return info


# ---------------------------------------------------------------------------
# Compose


def check_compose(root, docker, deadline, problems):
    where = "deploy/compose.yaml"
    try:
        with open(os.path.join(root, where), encoding="utf-8") as f:
            compose = yaml.safe_load(f)
    except (OSError, yaml.YAMLError) as e:
        problems.add(where, str(e))
        return
    services = compose.get("services") or {}
    server = services.get("server")
    if not problems.check(server, where, "no `server` service"):
        return
    build = server.get("build") or {}
    problems.check(build.get("dockerfile") == "deploy/Dockerfile", where,
                   "server must build deploy/Dockerfile")
    problems.check("BASE" in (build.get("args") or {}), where, "server build must pass BASE")
    state_mounts = [v for v in server.get("volumes") or []
                    if isinstance(v, str) and v.split(":")[1:2] == ["/var/lib/twistslam"]]
    problems.check(state_mounts, where, "server: no volume on /var/lib/twistslam")
    for v in state_mounts:
        problems.check(v.split(":")[0] in (compose.get("volumes") or {}), where,
                       f"server: volume {v.split(':')[0]} is not declared")
    hc = server.get("healthcheck") or {}
    test = hc.get("test") or []
    port = docker.get("port")
    problems.check(PROBE_BINARY in " ".join(test), where, "server: healthcheck must run the probe")
    problems.check(port_of(flag_value(test, "--addr")) == port, where,
                   "server: healthcheck must ask the listen port")
    grace = server.get("stop_grace_period")
    if problems.check(grace, where, "server: no stop_grace_period") and deadline:
        problems.check(parse_duration_s(grace) >= deadline, where,
                       f"server: stop_grace_period {grace} < the server's shutdown bound "
                       f"{deadline:g}s")
    clients = [(n, s) for n, s in services.items() if n != "server"]
    if not problems.check(clients, where, "no example client service"):
        return
    for name, svc in clients:
        dep = (svc.get("depends_on") or {}).get("server") or {}
        problems.check(dep.get("condition") == "service_healthy", where,
                       f"{name}: must wait for a healthy server")
        script = " ".join(svc.get("command") or []) if isinstance(svc.get("command"), list) \
            else str(svc.get("command"))
        script = re.sub(r"\\\n\s*", " ", script)
        problems.check("twistslam generate" in script, where, f"{name}: no `twistslam generate`")
        m = re.search(r"twistslam run .*--server\s+server:([0-9]+)", script)
        problems.check(m and int(m.group(1)) == port, where,
                       f"{name}: `twistslam run --server server:{port}` missing")


# ---------------------------------------------------------------------------
# Kubernetes


def load_yaml_docs(path):
    with open(path, encoding="utf-8") as f:
        return [d for d in yaml.safe_load_all(f) if d is not None]


def json_pointer_parts(pointer):
    return [p.replace("~1", "/").replace("~0", "~") for p in pointer.lstrip("/").split("/")]


def apply_json_patch(doc, ops, where):
    """RFC 6902 subset used by the overlays: add, remove, replace, test."""
    for op in ops:
        parts = json_pointer_parts(op["path"])
        parent = doc
        for p in parts[:-1]:
            parent = parent[int(p)] if isinstance(parent, list) else parent[p]
        last = parts[-1]
        if isinstance(parent, list):
            index = len(parent) if last == "-" else int(last)
        kind = op["op"]
        if kind == "test":
            current = parent[index] if isinstance(parent, list) else parent.get(last)
            if current != op["value"]:
                raise ValueError(f"{where}: patch test failed at {op['path']}: "
                                 f"{current!r} != {op['value']!r}")
        elif kind == "remove":
            if isinstance(parent, list):
                del parent[index]
            else:
                del parent[last]
        elif kind in ("add", "replace"):
            value = copy.deepcopy(op["value"])
            if isinstance(parent, list):
                if kind == "add":
                    parent.insert(index, value)
                else:
                    parent[index] = value
            else:
                if kind == "replace" and last not in parent:
                    raise ValueError(f"{where}: replace of missing {op['path']}")
                parent[last] = value
        else:
            raise ValueError(f"{where}: unsupported patch op {kind}")


def render_kustomization(directory, root, problems):
    """Renders a kustomization like `kustomize build` for the features used
    here. Returns (docs, generated config files {configmap name: {key: path}})."""
    where = os.path.relpath(os.path.join(directory, "kustomization.yaml"), root)
    try:
        kust = load_yaml_docs(os.path.join(directory, "kustomization.yaml"))[0]
    except (OSError, yaml.YAMLError, IndexError) as e:
        problems.add(where, str(e))
        return [], {}
    docs, configs = [], {}
    for res in kust.get("resources") or []:
        path = os.path.normpath(os.path.join(directory, res))
        if os.path.isdir(path):
            sub_docs, sub_configs = render_kustomization(path, root, problems)
            docs += sub_docs
            configs.update(sub_configs)
        elif problems.check(os.path.isfile(path), where, f"resource {res} does not exist"):
            docs += load_yaml_docs(path)
    for gen in kust.get("configMapGenerator") or []:
        data, files = {}, {}
        for spec in gen.get("files") or []:
            key, _, rel = spec.partition("=") if "=" in spec else (os.path.basename(spec), "", spec)
            path = os.path.normpath(os.path.join(directory, rel))
            if not problems.check(path.startswith(os.path.normpath(directory) + os.sep), where,
                                  f"generator file {rel} is outside the kustomization"):
                continue
            if problems.check(os.path.isfile(path), where, f"generator file {rel} missing"):
                with open(path, encoding="utf-8") as f:
                    data[key] = f.read()
                files[key] = path
        docs.append({"apiVersion": "v1", "kind": "ConfigMap",
                     "metadata": {"name": gen["name"]}, "data": data})
        configs[gen["name"]] = files
    for patch in kust.get("patches") or []:
        target = patch.get("target") or {}
        ops = yaml.safe_load(patch["patch"]) if "patch" in patch else \
            load_yaml_docs(os.path.join(directory, patch["path"]))[0]
        matched = [d for d in docs if d.get("kind") == target.get("kind")
                   and d["metadata"].get("name") == target.get("name")]
        if problems.check(matched, where, f"patch target {target} matches nothing"):
            for d in matched:
                try:
                    apply_json_patch(d, ops, where)
                except (ValueError, KeyError, IndexError, TypeError) as e:
                    problems.add(where, f"patch does not apply: {e}")
    return docs, configs


def selector_matches(selector, labels):
    return bool(selector) and all(labels.get(k) == v for k, v in selector.items())


def quantity(value):
    """CPU cores or memory bytes of a Kubernetes quantity."""
    s = str(value)
    units = {"m": 1e-3, "k": 1e3, "M": 1e6, "G": 1e9, "T": 1e12,
             "Ki": 2**10, "Mi": 2**20, "Gi": 2**30, "Ti": 2**40}
    m = re.fullmatch(r"([0-9.]+)([A-Za-z]*)", s)
    if not m or (m.group(2) and m.group(2) not in units):
        raise ValueError(f"bad quantity {value!r}")
    return float(m.group(1)) * units.get(m.group(2), 1)


def check_probe(probe, name, where, listen_port, tls, mounts, problems):
    if not problems.check(probe, where, f"{name} missing"):
        return
    handlers = [h for h in ("exec", "grpc", "httpGet", "tcpSocket") if h in probe]
    if not problems.check(len(handlers) == 1, where, f"{name}: needs exactly one handler"):
        return
    if "grpc" in probe:
        problems.check(not tls, where, f"{name}: the built-in grpc probe cannot speak TLS, "
                                       "but the server runs TLS (use the exec probe)")
        problems.check(probe["grpc"].get("port") == listen_port, where,
                       f"{name}: grpc probe port != listen port {listen_port}")
    elif "exec" in probe:
        argv = probe["exec"].get("command") or []
        problems.check(argv and argv[0].endswith(PROBE_BINARY), where,
                       f"{name}: exec probe must run {PROBE_BINARY}")
        problems.check(port_of(flag_value(argv, "--addr")) == listen_port, where,
                       f"{name}: probe --addr port != listen port {listen_port}")
        uses_tls = "--tls" in argv or flag_value(argv, "--tls-ca") is not None
        problems.check(uses_tls == tls, where,
                       f"{name}: probe TLS ({uses_tls}) != server TLS ({tls})")
        for flag in ("--tls-ca", "--token-file"):
            path = flag_value(argv, flag)
            if path:
                problems.check(under_mount(path, mounts), where,
                               f"{name}: {flag} {path} is not on a mounted volume")
        timeout_ms = flag_value(argv, "--timeout-ms")
        if timeout_ms:
            problems.check(int(timeout_ms) / 1000 <= probe.get("timeoutSeconds", 1), where,
                           f"{name}: probe --timeout-ms exceeds timeoutSeconds")
    else:
        problems.add(where, f"{name}: must ask grpc.health.v1 (grpc or exec probe)")


def check_k8s_variant(label, docs, configs, docker, problems):
    where = label
    by_kind = {}
    for d in docs:
        by_kind.setdefault(d.get("kind"), []).append(d)
    sets = by_kind.get("StatefulSet") or []
    if not problems.check(len(sets) == 1, where, "exactly one StatefulSet expected"):
        return
    sts = sets[0]
    spec = sts["spec"]
    pod = spec["template"]["spec"]
    labels = spec["template"]["metadata"].get("labels") or {}
    problems.check(selector_matches(spec["selector"].get("matchLabels"), labels), where,
                   "StatefulSet selector does not select its pod template")
    services = {s["metadata"]["name"]: s for s in by_kind.get("Service") or []}
    headless = services.get(spec.get("serviceName"))
    if problems.check(headless, where, f"serviceName {spec.get('serviceName')} has no Service"):
        problems.check(headless["spec"].get("clusterIP") == "None", where,
                       "the StatefulSet's Service must be headless (clusterIP: None)")
        problems.check(selector_matches(headless["spec"].get("selector"), labels), where,
                       "the headless Service does not select the pods")
    replicas = spec.get("replicas", 1)

    containers = [c for c in pod.get("containers") or [] if
                  SERVER_BINARY in " ".join((c.get("command") or []) + (c.get("args") or []))
                  or c.get("name") == "server"]
    if not problems.check(len(containers) == 1, where, "one server container expected"):
        return
    c = containers[0]
    argv = (c.get("command") or docker.get("entrypoint") or []) + (c.get("args") or [])
    problems.check(argv.count("--listen") + sum(a.startswith("--listen=") for a in argv) == 1,
                   where, "--listen must be given exactly once")
    listen_port = port_of(flag_value(argv, "--listen"))
    problems.check(listen_port, where, "server needs --listen HOST:PORT")
    ports = {p.get("name"): p.get("containerPort") for p in c.get("ports") or []}
    problems.check(listen_port in ports.values(), where,
                   f"containerPort {listen_port} (listen port) not declared")
    if headless:
        for sp in headless["spec"].get("ports") or []:
            target = sp.get("targetPort", sp.get("port"))
            problems.check(target in ports or target in ports.values(), where,
                           f"Service port {sp.get('name')} targets unknown port {target}")
        grpc_ports = [sp for sp in headless["spec"].get("ports") or []
                      if ports.get(sp.get("targetPort")) == listen_port
                      or sp.get("targetPort") == listen_port]
        problems.check(grpc_ports, where, "the headless Service does not expose the gRPC port")
    metrics = flag_value(argv, "--metrics-listen")
    if metrics:
        problems.check(port_of(metrics) in ports.values(), where,
                       "metrics port not declared as a containerPort")

    # Volumes and mounts.
    volumes = {v["name"]: v for v in pod.get("volumes") or []}
    claims = {t["metadata"]["name"]: t for t in spec.get("volumeClaimTemplates") or []}
    mounts = {}
    for m in c.get("volumeMounts") or []:
        problems.check(m["name"] in volumes or m["name"] in claims, where,
                       f"volumeMount {m['name']} has no volume or claim template")
        mounts[m["mountPath"]] = m["name"]
    state_dir = flag_value(argv, "--state-dir")
    if problems.check(state_dir, where, "server without --state-dir (sessions would not persist)"):
        problems.check(mounts.get(state_dir) in claims, where,
                       f"--state-dir {state_dir} is not a PersistentVolumeClaim template mount")
        for name, t in claims.items():
            problems.check("ReadWriteOnce" in (t["spec"].get("accessModes") or []), where,
                           f"claim {name}: ReadWriteOnce expected (one replica owns it)")
            problems.check(t["spec"].get("resources", {}).get("requests", {}).get("storage"),
                           where, f"claim {name}: no storage request")
    for flag in ("--config", "--auth-token-file", "--tls-cert", "--tls-key"):
        path = flag_value(argv, flag)
        if path:
            problems.check(under_mount(path, mounts), where,
                           f"{flag} {path} is not on a mounted volume")
    tls = flag_value(argv, "--tls-cert") is not None
    problems.check(tls == (flag_value(argv, "--tls-key") is not None), where,
                   "--tls-cert and --tls-key go together")
    secret_names = {v["secret"]["secretName"] for v in volumes.values() if "secret" in v}
    if tls:
        problems.check(any("tls" in s for s in secret_names), where, "TLS Secret not mounted")
    if flag_value(argv, "--auth-token-file"):
        problems.check(any("auth" in s or "token" in s for s in secret_names), where,
                       "token Secret not mounted")
    deadline = None
    config = flag_value(argv, "--config")
    if config:
        mount_path = max((m for m in mounts if under_mount(config, [m])), key=len, default=None)
        vol = volumes.get(mounts.get(mount_path)) if mount_path else None
        if problems.check(vol and "configMap" in vol, where, "--config must come from a ConfigMap"):
            cm_name = vol["configMap"]["name"]
            key = os.path.relpath(config, mount_path)
            cms = [d for d in by_kind.get("ConfigMap") or [] if d["metadata"]["name"] == cm_name]
            if problems.check(cms and key in (cms[0].get("data") or {}), where,
                              f"ConfigMap {cm_name} has no key {key}"):
                path = configs.get(cm_name, {}).get(key)
                if path:
                    deadline = shutdown_deadline_s(path, problems)
    grace = pod.get("terminationGracePeriodSeconds", 30)
    if deadline is not None:
        problems.check(grace >= deadline, where,
                       f"terminationGracePeriodSeconds {grace} < the server's shutdown bound "
                       f"{deadline:g}s (drain + deadline + 5 s)")
    else:
        problems.add(where, "cannot tell the server's shutdown deadline (no --config)")

    for name in ("startupProbe", "readinessProbe", "livenessProbe"):
        check_probe(c.get(name), name, where, listen_port, tls, list(mounts), problems)

    res = c.get("resources") or {}
    for kind in ("requests", "limits"):
        for r in ("cpu", "memory"):
            problems.check(r in (res.get(kind) or {}), where, f"resources.{kind}.{r} missing")
    for r in ("cpu", "memory"):
        try:
            if r in res.get("requests", {}) and r in res.get("limits", {}):
                problems.check(quantity(res["requests"][r]) <= quantity(res["limits"][r]),
                               where, f"{r} request above its limit")
        except ValueError as e:
            problems.add(where, str(e))

    psc = pod.get("securityContext") or {}
    problems.check(psc.get("runAsNonRoot") is True, where, "pod must set runAsNonRoot: true")
    if docker.get("user") and psc.get("runAsUser") is not None:
        problems.check(str(psc["runAsUser"]) == docker["user"].split(":")[0], where,
                       "runAsUser differs from the image's USER")
    csc = c.get("securityContext") or {}
    problems.check(csc.get("allowPrivilegeEscalation") is False, where,
                   "container must set allowPrivilegeEscalation: false")

    pdbs = by_kind.get("PodDisruptionBudget") or []
    if problems.check(pdbs, where, "no PodDisruptionBudget"):
        pdb = pdbs[0]["spec"]
        problems.check(selector_matches((pdb.get("selector") or {}).get("matchLabels"), labels),
                       where, "the PodDisruptionBudget does not select the pods")
        if "maxUnavailable" in pdb:
            problems.check(int(pdb["maxUnavailable"]) >= 1, where,
                           "maxUnavailable 0 blocks every node drain")
        elif "minAvailable" in pdb:
            problems.check(int(pdb["minAvailable"]) < replicas, where,
                           "minAvailable >= replicas blocks every node drain")
        else:
            problems.add(where, "PodDisruptionBudget without maxUnavailable/minAvailable")


def k8s_variants(root, problems):
    """(label, docs, configs) for the base and every overlay."""
    base = os.path.join(root, "deploy/k8s")
    out = []
    docs, configs = render_kustomization(base, root, problems)
    out.append(("deploy/k8s", docs, configs))
    overlays = os.path.join(base, "overlays")
    if os.path.isdir(overlays):
        for name in sorted(os.listdir(overlays)):
            d = os.path.join(overlays, name)
            if os.path.isfile(os.path.join(d, "kustomization.yaml")):
                docs, configs = render_kustomization(d, root, problems)
                out.append((f"deploy/k8s/overlays/{name}", docs, configs))
    return out


def yaml_files(root):
    files = [os.path.join(root, "deploy/compose.yaml")]
    for dirpath, _, names in os.walk(os.path.join(root, "deploy/k8s")):
        if os.path.basename(dirpath) == "config":
            continue  # server configs: OpenCV FileStorage YAML, checked above
        files += [os.path.join(dirpath, n) for n in sorted(names) if n.endswith((".yaml", ".yml"))]
    return files


def run_yamllint(root, problems):
    exe = shutil.which("yamllint")
    if not exe:
        print("note: yamllint not installed; lint skipped (apt-get install yamllint)")
        return False
    conf = os.path.join(root, "tests/deploy/yamllint.yaml")
    result = subprocess.run([exe, "-f", "parsable", "-c", conf] + yaml_files(root),
                            capture_output=True, text=True)
    for line in result.stdout.splitlines():
        problems.add("yamllint", os.path.relpath(line, root) if line.startswith(root) else line)
    if result.returncode != 0 and not result.stdout:
        problems.add("yamllint", result.stderr.strip() or f"exit {result.returncode}")
    return True


def check_all(root, problems, variants=None, lint=True):
    docker = check_dockerfile(root, problems)
    deadline = shutdown_deadline_s(docker["config"], problems) if docker.get("config") else None
    check_compose(root, docker, deadline, problems)
    for label, docs, configs in variants or k8s_variants(root, problems):
        check_k8s_variant(label, docs, configs, docker, problems)
        print(f"checked {label} ({len(docs)} objects)")
    if lint:
        run_yamllint(root, problems)
    return docker


# ---------------------------------------------------------------------------
# Self-test: each breakage must be reported.


def self_test(root):
    clean = Problems()
    docker = check_all(root, clean, lint=False)
    if clean.items:
        print("self-test needs clean manifests first:\n  " + "\n  ".join(clean.items))
        return 1
    base = k8s_variants(root, Problems())[0]

    def server(docs):
        sts = [d for d in docs if d["kind"] == "StatefulSet"][0]
        return sts, sts["spec"]["template"]["spec"]["containers"][0]

    def set_arg(docs, flag, value):
        argv = server(docs)[1]["command"]
        argv[argv.index(flag) + 1] = value

    breakages = {
        "no readiness probe": lambda d: server(d)[1].pop("readinessProbe"),
        "no liveness probe": lambda d: server(d)[1].pop("livenessProbe"),
        "grpc probe with TLS": lambda d: server(d)[1].__setitem__(
            "readinessProbe", {"grpc": {"port": 50051}}),
        "probe on wrong port": lambda d: set_probe_addr(server(d)[1], "localhost:1"),
        "grace below deadline": lambda d: server(d)[0]["spec"]["template"]["spec"].__setitem__(
            "terminationGracePeriodSeconds", 1),
        "no PDB": lambda d: d.remove([x for x in d if x["kind"] == "PodDisruptionBudget"][0]),
        "state dir not a claim": lambda d: set_arg(d, "--state-dir", "/tmp"),
        "listen port not declared": lambda d: set_arg(d, "--listen", "0.0.0.0:6000"),
        "no resources": lambda d: server(d)[1].pop("resources"),
        "secret not mounted": lambda d: set_arg(d, "--tls-key", "/srv/tls.key"),
        "service not headless": lambda d: [x for x in d if x["kind"] == "Service"][0][
            "spec"].pop("clusterIP"),
        "mount without volume": lambda d: server(d)[1]["volumeMounts"].append(
            {"name": "ghost", "mountPath": "/ghost"}),
    }

    def set_probe_addr(container, addr):
        argv = container["livenessProbe"]["exec"]["command"]
        argv[argv.index("--addr") + 1] = addr

    failures = 0
    for name, breakage in breakages.items():
        docs = copy.deepcopy(base[1])
        breakage(docs)
        problems = Problems()
        check_k8s_variant("self-test", docs, base[2], docker, problems)
        if problems.items:
            print(f"ok   {name}: {problems.items[0]}")
        else:
            print(f"FAIL {name}: not detected")
            failures += 1
    # The config reader: OpenCV-style YAML, JSON, and a header-less file.
    cases = (("%YAML:1.0\n---\nshutdown_deadline_s: 30\nslam:\n  seed: 3\n", 40.0),
             ('{"shutdown_deadline_s": 12, "drain_timeout_s": 1}', 18.0),
             ("%YAML:1.0\ndrain_timeout_s: 20\n", 35.0),
             ("shutdown_deadline_s: 30\n", None))
    for text, expect in cases:
        try:
            value = settings_bound_s(parse_config_text(text))[1]
        except ValueError:
            value = None
        if value != expect:
            print(f"FAIL config parse {text!r}: {value} != {expect}")
            failures += 1
    print(f"{len(breakages) + len(cases) - failures} passed, {failures} failed")
    return 1 if failures else 0


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--root", default=os.path.normpath(
        os.path.join(os.path.dirname(os.path.abspath(__file__)), "../..")))
    parser.add_argument("--self-test", action="store_true")
    args = parser.parse_args()
    if args.self_test:
        return self_test(args.root)
    problems = Problems()
    check_all(args.root, problems)
    for p in problems.items:
        print("PROBLEM " + p)
    print(f"manifest check: {len(problems.items)} problem(s)")
    return 1 if problems.items else 0


if __name__ == "__main__":
    sys.exit(main())
