"""The Kubernetes manifests of deploy/k8s/ (issue 18), read with PyYAML (python3-yaml) and
checked against each other, the Dockerfile, the server's sources and a real server.

kubectl, kind and a cluster are not available where the tests run, so nothing is applied:
this checks what can be checked without one.
- consistent: the kustomization lists every manifest; the Deployment's selector matches its
  pod labels, and both Services select those pods; the Services' targetPort and the probes'
  port name the container's port, which is the --port of its command and the scrape
  annotation's port; the HPA scales this Deployment on a Pods metric that the
  prometheus-adapter rule serves and that GET /metrics has, as a gauge; the pod runs as the
  Dockerfile's user and names paths the image has;
- the drain: preStop sleeps, and terminationGracePeriodSeconds covers that sleep plus the
  server's drain bound (HTTP_DRAIN_S in server/http.c); memory limit >= request;
- real: the container's own command, run by /bin/sh as the kubelet would (POD_NAME set as the
  downward API sets it), with only its address and the assets folder moved to this machine,
  starts a server whose startup, liveness and readiness probe paths answer 200 on the probed
  port, whose instance name is the pod's name without dashes (last 16 characters), whose
  job ids carry it, and which exits 0 on SIGTERM.

Python standard library + PyYAML."""
import glob
import json
import os
import re
import select
import signal
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from nstest_http import Checks, Server, own_leaks, sanitizer_env, small_scene  # noqa: E402

try:
    import yaml
except ImportError:  # scripts/setup.sh installs python3-yaml with the test packages
    yaml = None

SOURCE = os.environ.get("NSCATTER_SOURCE_DIR",
                        os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
K8S = os.path.join(SOURCE, "deploy", "k8s")
POD_NAME = "nscatter-7d9f8c6b5-x2x9z"


def load():
    docs = {}
    for path in sorted(glob.glob(os.path.join(K8S, "*.yaml"))):
        with open(path) as f:
            docs[os.path.basename(path)] = [d for d in yaml.safe_load_all(f) if d]
    return docs


def of_kind(docs, kind):
    return [d for file_docs in docs.values() for d in file_docs if d.get("kind") == kind]


def quantity_bytes(q):
    units = {"Ki": 2**10, "Mi": 2**20, "Gi": 2**30, "k": 10**3, "M": 10**6, "G": 10**9}
    m = re.match(r"^(\d+)([A-Za-z]*)$", str(q))
    return int(m.group(1)) * units.get(m.group(2), 1) if m else None


def test_consistent(t, docs):
    kust = docs.get("kustomization.yaml", [{}])[0]
    listed = set(kust.get("resources", []))
    manifests = {f for f, ds in docs.items() if any("apiVersion" in d and "kind" in d for d in ds)
                 and f != "kustomization.yaml"}
    t.equal(listed, manifests, "kustomization.yaml lists every manifest")
    deps, svcs, hpas = of_kind(docs, "Deployment"), of_kind(docs, "Service"), \
        of_kind(docs, "HorizontalPodAutoscaler")
    t.equal((len(deps), len(hpas)), (1, 1), "one Deployment, one HPA")
    t.check(len(svcs) >= 1, "a Service")
    dep = deps[0]
    pod = dep["spec"]["template"]
    labels = pod["metadata"]["labels"]
    sel = dep["spec"]["selector"]["matchLabels"]
    t.check(sel.items() <= labels.items(), f"the Deployment selects its pods: {sel} {labels}")
    container = pod["spec"]["containers"][0]
    ports = {p["name"]: p["containerPort"] for p in container["ports"]}
    for svc in svcs:
        name = svc["metadata"]["name"]
        t.check(svc["spec"]["selector"].items() <= labels.items(),
                f"Service {name} selects the pods")
        for p in svc["spec"]["ports"]:
            t.check(p["targetPort"] in ports or p["targetPort"] in ports.values(),
                    f"Service {name} targets a container port: {p['targetPort']}")
    hpa = hpas[0]
    ref = hpa["spec"]["scaleTargetRef"]
    t.equal((ref.get("apiVersion"), ref.get("kind"), ref.get("name")),
            (dep["apiVersion"], "Deployment", dep["metadata"]["name"]), "the HPA scales it")
    t.equal(hpa["apiVersion"], "autoscaling/v2", "autoscaling/v2")
    t.check(hpa["spec"]["minReplicas"] >= 2 and hpa["spec"]["maxReplicas"] >=
            hpa["spec"]["minReplicas"], "replicas: at least 2 (one can drain)")
    metrics = hpa["spec"]["metrics"]
    t.check(len(metrics) == 1 and metrics[0]["type"] == "Pods", "one Pods metric")
    metric = metrics[0]["pods"]["metric"]["name"]
    t.equal(metric, "nscatter_queue_depth", "on the queue depth")
    rules = docs["prometheus-adapter-values.yaml"][0]["rules"]["custom"]
    t.check(any(r["name"]["as"] == metric and metric in r["seriesQuery"]
                and "<<.LabelMatchers>>" in r["metricsQuery"] for r in rules),
            "prometheus-adapter serves it per pod")

    # The drain.
    spec = pod["spec"]
    stop = container["lifecycle"]["preStop"]["exec"]["command"]
    t.check(stop[0] == "sleep" and stop[1].isdigit(), f"preStop sleeps: {stop}")
    with open(os.path.join(SOURCE, "server", "http.c")) as f:
        drain = int(re.search(r"#define HTTP_DRAIN_S (\d+)", f.read()).group(1))
    grace = spec["terminationGracePeriodSeconds"]
    t.check(grace >= int(stop[1]) + drain,
            f"terminationGracePeriodSeconds {grace} >= preStop {stop[1]} + drain {drain}")
    t.equal(dep["spec"]["strategy"]["rollingUpdate"]["maxUnavailable"], 0,
            "a rollout adds before it drains")
    res = container["resources"]
    req, lim = quantity_bytes(res["requests"]["memory"]), quantity_bytes(res["limits"]["memory"])
    t.check(req and lim and lim >= req, f"memory limit >= request: {res}")

    # The image: its user and paths.
    with open(os.path.join(SOURCE, "Dockerfile")) as f:
        dockerfile = f.read()
    uid = re.search(r"--uid (\d+)", dockerfile).group(1)
    t.equal(str(spec["securityContext"]["runAsUser"]), uid, "runs as the image's user")
    script = container["command"][-1]
    for path in re.findall(r"/usr/share/nscatter/\S+", script):
        t.check("/usr/share/nscatter/scenes" in dockerfile and path.startswith(
            "/usr/share/nscatter/scenes"), f"{path} is in the image")
    port = int(re.search(r"--port (\d+)", script).group(1))
    t.equal(ports.get("http"), port, "the container port is the server's --port")
    ann = pod["metadata"].get("annotations", {})
    t.equal((ann.get("prometheus.io/port"), ann.get("prometheus.io/path")),
            (str(port), "/metrics"), "scraped at its /metrics")


def read_port(proc, log, timeout=240):
    deadline = time.monotonic() + timeout
    line = b""
    fd = proc.stdout.fileno()
    while not line.endswith(b"\n"):
        if time.monotonic() > deadline or proc.poll() is not None:
            raise RuntimeError(f"the container's command did not start a server: {log()}")
        if select.select([fd], [], [], 0.5)[0]:
            chunk = os.read(fd, 1)
            if chunk:
                line += chunk
    m = re.match(r"^listening on http://127\.0\.0\.1:(\d+)$", line.decode().strip())
    if not m:
        raise RuntimeError(f"unexpected first line {line!r}")
    return int(m.group(1))


def test_container_command(t, docs):
    """The container's command as the kubelet runs it: /bin/sh -c SCRIPT with POD_NAME."""
    container = of_kind(docs, "Deployment")[0]["spec"]["template"]["spec"]["containers"][0]
    command = list(container["command"])
    t.equal(command[:2], ["/bin/sh", "-c"], "a shell, for the instance name")
    script = command[2]
    t.check(re.match(r"^exec nscatter serve ", script), "exec: nscatter is PID 1 and gets SIGTERM")
    # This machine's address and assets; the rest as written.
    script = script.replace("--host 0.0.0.0", "--host 127.0.0.1")
    script = re.sub(r"--port \d+", "--port 0", script)
    script = script.replace("/usr/share/nscatter/scenes/assets",
                            os.path.join(SOURCE, "scenes", "assets"))
    bindir = tempfile.mkdtemp(prefix="nscatter-k8s-")
    binary = os.path.realpath(os.environ["NSCATTER_BIN"])
    os.symlink(binary, os.path.join(bindir, "nscatter"))
    env = sanitizer_env()
    env["PATH"] = bindir + os.pathsep + env.get("PATH", "")
    for e in container.get("env", []):
        if "value" in e:
            env[e["name"]] = e["value"]
        elif e.get("valueFrom", {}).get("fieldRef", {}).get("fieldPath") == "metadata.name":
            env[e["name"]] = POD_NAME
    t.equal(env.get("POD_NAME"), POD_NAME, "POD_NAME from the downward API")
    log = tempfile.NamedTemporaryFile(prefix="nscatter-k8s-", suffix=".log", delete=False)

    def log_text():
        with open(log.name, errors="replace") as f:
            return f.read()

    proc = subprocess.Popen(["/bin/sh", "-c", script], env=env, stdout=subprocess.PIPE,
                            stderr=log, stdin=subprocess.DEVNULL)
    try:
        srv = Endpoint(read_port(proc, log_text))
        want = re.sub(r"[^a-z0-9]", "", POD_NAME)[-16:]
        for probe in ("startupProbe", "livenessProbe", "readinessProbe"):
            get = container[probe]["httpGet"]
            t.equal(get["port"], "http", f"{probe} on the http port")
            status, h, body = srv.request("GET", get["path"])
            t.equal(status, 200, f"{probe} {get['path']} answers 200")
            t.equal(h.get("x-nscatter-instance"), want, f"instance {want}, the pod's name")
        status, h, body = srv.request("POST", "/v1/renders", json.dumps(small_scene(8, 8)),
                                      {"Content-Type": "application/json",
                                       "Prefer": "respond-async"})
        jid = json.loads(body).get("id", "") if status == 202 else ""
        t.check(jid.startswith(want + "-"), f"job ids name the pod: {jid}")
        status, h, body = srv.request("GET", "/metrics")
        t.check(status == 200 and "# TYPE nscatter_queue_depth gauge" in body.decode(),
                "the HPA's metric is a gauge of /metrics")
        proc.send_signal(signal.SIGTERM)  # what the kubelet sends after preStop
        code = proc.wait(60)
        t.equal(code, 0, "SIGTERM: exit 0")
        leaks = own_leaks(log_text(), binary)
        t.check(not leaks, f"no leak through nscatter's own code: {leaks[:1]}")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        proc.stdout.close()
        os.unlink(log.name)
        os.unlink(os.path.join(bindir, "nscatter"))
        os.rmdir(bindir)


class Endpoint:
    def __init__(self, port):
        self.port = port

    connection = Server.connection
    request = Server.request


def main():
    t = Checks()
    if yaml is None:
        t.check(False, "PyYAML is missing (apt-get install python3-yaml; scripts/setup.sh test)")
        return t.report()
    docs = load()
    t.run(test_consistent, docs)
    t.run(test_container_command, docs)
    return t.report()


if __name__ == "__main__":
    sys.exit(main())
