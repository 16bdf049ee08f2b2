"""GET /openapi.json (server/openapi.json, docs/http.md "OpenAPI") against the real server:
- the document the server answers is the checked-in file, byte for byte, and a valid
  OpenAPI 3.1 document by openapi-spec-validator; its info.version is the service's;
- its enums agree with the sources: the problem codes with server/problem.h and the ns_status
  table of render/include/nscatter.h (each code under the statuses it is answered with), the
  methods and components with nscatter.h, the presets with /v1/materials, the fixed limits
  with /v1/info;
- every route the server answers is described: each route template of server/http.c's
  route_name table, probed with a method no route takes, answers 405 with an Allow header
  that lists exactly the methods the document describes for that path; and the reverse:
  every path and method of the document answers something other than 404 or 405;
- a representative set of real requests (images, every problem status, asynchronous jobs and
  their events, cancels and discards, sweeps, validate, info, materials, metrics) is answered
  with a status, content type and required headers the document promises for that
  operation, and every JSON body (and every event's data) validates against the documented
  schema, with jsonschema;
- the shipped scenes validate against the document's Scene schema, scenes the parser refuses
  are refused by the schema too where a schema can say why, and the rules it cannot express
  are listed (the schema accepts those scenes, the server refuses them).

The document is validated against the OpenAPI Initiative's schemas by the npm package
@seriousme/openapi-schema-validator (web/package.json, tests/openapi_validate.mjs), and also
by openapi-spec-validator where the Python has it (Debian packages it from trixie on, not in
bookworm). jsonschema comes from the running Python or Debian's python3-jsonschema."""
import copy
import json
import os
import re
import secrets
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from nstest_http import Checks, Server, parse_raw_response, small_scene  # noqa: E402
from nstest_jobs import PtRate, post_json, read_events, wait_idle, wait_state  # noqa: E402


def _import_jsonschema():
    try:
        import jsonschema
    except ImportError:
        # Debian's packages install into the system Python's dist-packages, which a python3
        # from pyenv or a virtual environment does not search.
        sys.path.append("/usr/lib/python3/dist-packages")
        import jsonschema
    return jsonschema


def _import_spec_validator():
    """openapi-spec-validator where the Python has it (Debian packages it from trixie on,
    bookworm does not); the document is always checked by the npm validator too."""
    try:
        import openapi_spec_validator
        return openapi_spec_validator
    except ImportError:
        return None


try:
    jsonschema = _import_jsonschema()
except ImportError as e:
    print(f"FAIL: jsonschema is missing ({e}): Debian's python3-jsonschema "
          "(scripts/setup.sh test installs it)", file=sys.stderr)
    sys.exit(1)
openapi_spec_validator = _import_spec_validator()

SOURCE = os.environ.get("NSCATTER_SOURCE_DIR",
                        os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
MAX_BODY = 256 * 1024
# Job ids carry the instance's name (NAME-<32 hex>), as behind a load balancer; the service's
# own VRL limit is below the hard one that the Scene schema states.
INSTANCE = "oa1"
MAX_VRLS = 200000
HTTP_METHODS = ("get", "head", "post", "put", "delete", "patch", "options", "trace")
JSON_TYPES = ("application/json", "application/problem+json")


def read_source(path):
    with open(os.path.join(SOURCE, path), encoding="utf-8") as f:
        return f.read()


def base_type(content_type):
    return content_type.split(";")[0].strip().lower()


# ---------------------------------------------------------------------------------------
# The document: references, schemas, operations
# ---------------------------------------------------------------------------------------
class Doc:
    def __init__(self, doc):
        self.doc = doc
        self.defs = self._rewrite(doc["components"]["schemas"])

    @staticmethod
    def _rewrite(node):
        """Schema references into a document of their own: #/components/schemas/X becomes
        #/$defs/X, so that jsonschema resolves them without a registry (which differs
        between the versions Debian and pip ship)."""
        if isinstance(node, dict):
            out = {}
            for k, v in node.items():
                if k == "$ref" and isinstance(v, str) and v.startswith("#/components/schemas/"):
                    out[k] = "#/$defs/" + v[len("#/components/schemas/"):]
                else:
                    out[k] = Doc._rewrite(v)
            return out
        if isinstance(node, list):
            return [Doc._rewrite(v) for v in node]
        return node

    def resolve(self, node):
        """Follows a $ref to components (parameters, responses, headers, request bodies)."""
        while isinstance(node, dict) and "$ref" in node:
            at = self.doc
            for part in node["$ref"].lstrip("#/").split("/"):
                at = at[part.replace("~1", "/").replace("~0", "~")]
            node = at
        return node

    def validator(self, schema):
        root = self._rewrite(copy.deepcopy(schema))
        if not isinstance(root, dict):
            root = {"allOf": [root]}
        root["$defs"] = self.defs
        return jsonschema.Draft202012Validator(root)

    def errors(self, schema, value):
        """Validation errors of value against schema, as short lines."""
        return [f"{'/'.join(str(p) for p in e.absolute_path) or '(root)'}: {e.message[:300]}"
                for e in self.validator(schema).iter_errors(value)]

    def schema(self, name):
        return {"$ref": f"#/components/schemas/{name}"}

    def match(self, path):
        """The path template of the document that a concrete path falls under: a fixed path
        before a templated one (as OpenAPI says), then the one with fewest parameters."""
        path = path.split("?")[0]
        if path in self.doc["paths"]:
            return path
        found = []
        for template in self.doc["paths"]:
            if "{" not in template:
                continue
            pattern = "^" + re.sub(r"\\\{[^}]+\\\}", "[^/]+", re.escape(template)) + "$"
            if re.match(pattern, path):
                found.append((template.count("{"), template))
        return min(found)[1] if found else None

    def methods(self, template):
        return {m.upper() for m in self.doc["paths"].get(template, {}) if m in HTTP_METHODS}

    def operation(self, template, method):
        return self.doc["paths"].get(template, {}).get(method.lower())


def check_headers_of(t, d, what, declared, headers):
    """Required headers present; every declared header that is present fits its schema."""
    for name, h in (declared or {}).items():
        h = d.resolve(h)
        value = headers.get(name.lower())
        if h.get("required"):
            t.check(value is not None, f"{what}: required header {name} present: {sorted(headers)}")
        if value is None or "schema" not in h:
            continue
        schema = h["schema"]
        typed = value
        if schema.get("type") == "integer":
            typed = int(value) if value.strip().isdigit() else value
        errs = d.errors(schema, typed)
        t.check(not errs, f"{what}: header {name}: {value!r}: {errs}")


def check_answer(t, d, what, method, path, status, headers, body, template=None):
    """The answer is one the document promises for this operation: its status, its content
    type, its required headers, and a JSON body that validates against the schema. Returns
    the parsed JSON body (or None)."""
    template = template or d.match(path)
    if not t.check(template, f"{what}: {path} falls under a documented path"):
        return None
    op = d.operation(template, method)
    if status == 405:
        resp = d.resolve({"$ref": "#/components/responses/MethodNotAllowed"})
        allow = {m.strip() for m in headers.get("allow", "").split(",") if m.strip()}
        t.equal(allow, d.methods(template), f"{what}: Allow of {template} is what the document lists")
    else:
        if not t.check(op, f"{what}: {method} {template} is documented"):
            return None
        resp = op["responses"].get(str(status))
        if not t.check(resp is not None, f"{what}: status {status} is documented for {method} "
                                         f"{template}: {sorted(op['responses'])}"):
            return None
        resp = d.resolve(resp)
    check_headers_of(t, d, what, resp.get("headers"), headers)
    content = resp.get("content")
    if method == "HEAD":
        t.equal(body, b"", f"{what}: HEAD has no body")
        get = d.operation(template, "GET")
        get_resp = d.resolve(get["responses"].get(str(status), {})) if get else {}
        content = get_resp.get("content")
    if status in (204, 304) or not content:
        t.check(not body, f"{what}: no body with {status}: {body[:100]!r}")
        return None
    ctype = headers.get("content-type", "")
    keys = [k for k in content if k.lower() == ctype.lower() or base_type(k) == base_type(ctype)]
    if not t.check(keys, f"{what}: content type {ctype!r} is documented for {status}: {sorted(content)}"):
        return None
    if method == "HEAD" or base_type(ctype) not in JSON_TYPES:
        return None
    try:
        value = json.loads(body.decode("utf-8"))
    except ValueError:
        t.check(False, f"{what}: the body is JSON: {body[:200]!r}")
        return None
    schema = content[keys[0]].get("schema")
    if schema is not None:
        errs = d.errors(schema, value)
        t.check(not errs, f"{what}: the body validates against the documented schema: {errs[:5]}")
    return value


def request(srv, method, path, body=None, headers=None):
    h = dict(headers or {})
    if body is not None and not isinstance(body, (bytes, bytearray)):
        body = json.dumps(body).encode()
        h.setdefault("Content-Type", "application/json")
    return srv.request(method, path, body, h)


def replay(t, d, srv, what, method, path, body=None, headers=None, want=None):
    """One request, checked against the document; returns (status, headers, parsed JSON)."""
    status, h, raw = request(srv, method, path, body, headers)
    if want is not None:
        t.equal(status, want, f"{what}: status")
    value = check_answer(t, d, what, method, path, status, h, raw)
    return status, h, value, raw


def check_events(t, d, what, path, stream):
    """Each event's data validates against the schema the document names for its event."""
    check_answer(t, d, what, "GET", path, stream.status, stream.headers, b"" if stream.events else stream.body)
    template = d.match(path)
    media = d.resolve(d.operation(template, "GET")["responses"]["200"])["content"]["text/event-stream"]
    names = media.get("x-event-schemas", {})
    t.check(stream.events, f"{what}: events came")
    for e in stream.events:
        ref = names.get(e.name)
        if not t.check(ref, f"{what}: event {e.name!r} is documented: {sorted(names)}"):
            continue
        errs = d.errors({"$ref": ref}, e.json())
        t.check(not errs, f"{what}: event {e.id} {e.name} data validates: {errs[:3]}")
    return [e.name for e in stream.events]


# ---------------------------------------------------------------------------------------
# (1) The document itself
# ---------------------------------------------------------------------------------------
def test_document_is_valid(t, srv, d):
    status, headers, raw = srv.request("GET", "/openapi.json")
    t.equal(status, 200, "GET /openapi.json")
    t.equal(headers.get("content-type"), "application/json", "content type")
    t.equal(headers.get("cache-control"), "no-cache", "Cache-Control")
    with open(os.path.join(SOURCE, "server", "openapi.json"), "rb") as f:
        t.check(raw == f.read(), "the answer is server/openapi.json as checked in (rebuild?)")
    t.equal(d.doc.get("openapi"), "3.1.0", "openapi version")
    # The OpenAPI Initiative's own schemas, through the npm validator (web/package.json).
    run = subprocess.run(["node", os.path.join(SOURCE, "tests", "openapi_validate.mjs"),
                          os.path.join(SOURCE, "server", "openapi.json")],
                         capture_output=True, text=True, timeout=120)
    t.check(run.returncode == 0, f"@seriousme/openapi-schema-validator: {run.stdout[:2000]}"
            f"{run.stderr[:500]}")
    if openapi_spec_validator:
        try:
            validate = getattr(openapi_spec_validator, "validate", None) or \
                openapi_spec_validator.validate_spec
            validate(d.doc)
            t.check(True, "openapi-spec-validator")
        except Exception as e:  # its exceptions differ between versions
            t.check(False, f"openapi-spec-validator: {type(e).__name__}: {str(e)[:2000]}")
    # Every example given in a schema validates against it.
    for name, schema in d.doc["components"]["schemas"].items():
        for i, example in enumerate(schema.get("examples", [])):
            errs = d.errors(d.schema(name), example)
            t.check(not errs, f"schema {name} example {i}: {errs[:3]}")


def test_version_and_enums_agree_with_sources(t, srv, d):
    header = read_source("render/include/nscatter.h")
    ns_version = re.search(r'#define NS_VERSION "([^"]+)"', header).group(1)
    t.equal(d.doc["info"]["version"], ns_version, "info.version is NS_VERSION")
    status, _, raw = srv.request("GET", "/v1/info")
    info = json.loads(raw)
    t.equal(d.doc["info"]["version"], info.get("version"), "info.version is /v1/info's version")

    schemas = d.doc["components"]["schemas"]
    methods = re.findall(r'X\(NS_METHOD_[A-Z]+, \d+, "([a-z]+)"\)', header)
    components = re.findall(r'X\(NS_COMPONENT_[A-Z]+, \d+, "([a-z]+)"\)', header)
    t.check(methods and components, "methods and components read from nscatter.h")
    t.equal(schemas["RenderMethod"]["enum"], methods, "RenderMethod is NS_METHODS")
    t.equal(schemas["Component"]["enum"], components, "Component is NS_COMPONENTS")
    # The render settings' defaults are written in three places: nscatter.h (what the parser
    # applies), the document, and the web page's placeholders. They must say the same.
    defaults = {m.group(1).lower(): float(m.group(2)) for m in
                re.finditer(r"#define NS_DEFAULT_([A-Z_]+) ([0-9.]+)[uf]?\b", header)}
    t.check(len(defaults) >= 10, f"numeric defaults read from nscatter.h: {sorted(defaults)}")
    page = read_source("web/index.html")
    for key, value in defaults.items():
        prop = schemas["RenderSettings"]["properties"].get(key, {})
        t.equal(prop.get("default"), value, f"RenderSettings.{key}.default is NS_DEFAULT_{key.upper()}")
        field = re.search(r'id="%s"[^>]*data-default="([^"]*)"' % key.replace("_", "-"), page)
        if field:
            t.equal(float(field.group(1)), value, f"the web page's {key} default is NS_DEFAULT_{key.upper()}")
    # The settings named by strings: the parser's names (its arrays in io/scene_json.c), the
    # document's enums, and the web page's options (a select per setting; none for a mesh's
    # normals) say the same.
    parser = read_source("io/scene_json.c")
    named = {}
    for array, schema, key, select_id in (("tables_names", "RenderSettings", "tables", "tables"),
                                          ("accumulation_names", "RenderSettings", "accumulation",
                                           "accumulation"),
                                          ("beam_names", "RenderSettings", "vrl_beams", "vrl-beams"),
                                          ("boundary_names", "RenderSettings", "boundary", "boundary"),
                                          ("shading_names", "Mesh", "normals", None)):
        names = re.search(r"%s\[\] = \{([^}]*)\}" % array, parser)
        named[key] = re.findall(r'"([a-z]+)"', names.group(1)) if names else []
        t.check(named[key], f"the parser's {array} read from io/scene_json.c")
        prop = schemas[schema]["properties"].get(key, {})
        t.equal(prop.get("enum"), named[key], f"{schema}.{key}.enum is the parser's {array}")
        if select_id:
            select = re.search(r'<select id="%s">(.*?)</select>' % select_id, page, re.S)
            options = re.findall(r'<option value="([a-z]+)"', select.group(1)) if select else []
            t.equal(sorted(options), sorted(named[key]), f"the web page offers every {key} value")
    # render.tables' default (an absent key): the parser's, the document's, the page's fallback.
    absent = re.search(r"\.tables = NS_TABLES_([A-Z]+)\}", parser)
    prop = schemas["RenderSettings"]["properties"].get("tables", {})
    t.equal(prop.get("default"), absent.group(1).lower() if absent else None,
            "RenderSettings.tables.default is what the parser gives an absent key")
    fallback = re.search(r"key: 'tables', id: 'tables', fallback: \(\) => '([a-z]+)'",
                         read_source("web/app.js"))
    t.equal(fallback.group(1) if fallback else None, prop.get("default"),
            "the web page shows the tables default when the scene leaves the key out")
    status, _, raw = srv.request("GET", "/v1/materials")
    presets = [m["name"] for m in json.loads(raw)["materials"]]
    t.equal(sorted(schemas["PresetName"]["enum"]), sorted(presets), "PresetName is /v1/materials")
    for key, s in schemas["Limits"]["properties"].items():
        if "const" in s:
            t.equal(info["limits"].get(key), s["const"], f"limits.{key}")
    t.equal(info["limits"].get("max_vrls"), MAX_VRLS, "limits.max_vrls is --max-vrls")

    # The codes: problem.h's own, with their statuses, and the ns_status names.
    own = {code: int(st) for st, code in
           re.findall(r'X\(PROBLEM_[A-Z_]+, (\d+), "([a-z_]+)"', read_source("server/problem.h"))}
    ns = {name: int(st) for name, st in
          re.findall(r'X\(NS_[A-Z_]+, -?\d+, "([a-z_]+)", "[^"]*", (\d+)\)', header)}
    ns.pop("ok", None)
    t.check(len(own) >= 14 and len(ns) >= 12, f"codes read from the sources: {own} {ns}")
    t.equal(sorted(schemas["ProblemCode"]["enum"]), sorted(list(own) + list(ns)),
            "ProblemCode lists every code of problem.h and of the ns_status table")
    # Each response's problem schema names its status and the codes it carries.
    by_status = {}

    def collect(node):
        if isinstance(node, dict):
            for part in node.get("allOf", []):
                props = part.get("properties", {}) if isinstance(part, dict) else {}
                if "const" in props.get("status", {}) and "enum" in props.get("code", {}):
                    by_status.setdefault(props["status"]["const"], set()).update(props["code"]["enum"])
            for v in node.values():
                collect(v)
        elif isinstance(node, list):
            for v in node:
                collect(v)
    collect(d.doc)
    for code, st in own.items():
        t.check(code in by_status.get(st, ()), f"{code} ({st}) is documented under {st}")
    for code, st in ns.items():
        if code == "cancelled":
            continue  # only ever the error of a cancelled job, never an answer
        t.check(code in by_status.get(st, ()), f"{code} ({st}) is documented under {st}")
        # /readyz and every render answer 503 with the reason the context was not made.
        t.check(code in by_status.get(503, ()), f"{code} is documented under 503 (no context)")
    for st, codes in by_status.items():
        for code in codes:
            t.check(own.get(code) == st or ns.get(code) == st or (st == 503 and code in ns),
                    f"{code} under {st} is answered with that status")


# ---------------------------------------------------------------------------------------
# (2) Every route described, every description answered
# ---------------------------------------------------------------------------------------
def route_templates():
    """The route templates of server/http.c's route_name table (what logs and metrics use)."""
    templates = re.findall(r'\[ROUTE_[A-Z_]+\] = "(/[^"]*)"', read_source("server/http.c"))
    return templates + ["/"]  # "/" is the page's other form (route /{file})


def concrete(template, jobs):
    kind = "sweep" if template.startswith("/v1/sweeps/") else "render"
    return (template.replace("{id}", jobs[kind]).replace("{n}", "0").replace("{file}", "app.js"))


def test_every_route_is_described(t, srv, d, jobs):
    templates = route_templates()
    t.check(len(templates) >= 19, f"route templates read from http.c: {templates}")
    for template in templates:
        t.check(template in d.doc["paths"], f"{template} is a path of the document")
        path = concrete(template, jobs)
        t.equal(d.match(path), template, f"{path} falls under {template}")
        # No route takes PATCH: the 405 lists the methods the route takes.
        status, headers, raw = srv.request("PATCH", path)
        t.equal(status, 405, f"PATCH {path}")
        allow = {m.strip() for m in headers.get("allow", "").split(",") if m.strip()}
        t.equal(d.methods(template), allow, f"{template}: documented methods are its Allow")
        check_answer(t, d, f"PATCH {path}", "PATCH", path, status, headers, raw, template)
    documented = set(d.doc["paths"])
    t.equal(documented, set(templates), "the document describes the routes and nothing else")
    # Paths that are no route: 404, and the document has no path for them either.
    for path in ("/v1/nope", f"/v1/renders/{jobs['render']}/nope",
                 f"/v1/sweeps/{jobs['sweep']}/sheet.jpg", "/a/b"):
        status, headers, raw = srv.request("GET", path)
        t.equal(status, 404, f"GET {path}")
        t.equal(d.match(path), None, f"{path} is not a documented path")


def test_every_description_is_answered(t, srv, d, jobs, discard):
    """Each documented path and method, with a real id and a body it takes: never 404/405."""
    bodies = {
        ("/v1/renders", "POST"): small_scene(16, 16),
        ("/v1/renders/validate", "POST"): small_scene(16, 16),
        ("/v1/sweeps", "POST"): {"scene": small_scene(16, 16), "variants": [{}]},
    }
    for template, item in d.doc["paths"].items():
        for method in sorted(m.upper() for m in item if m in HTTP_METHODS):
            ids = discard if method == "DELETE" else jobs
            path = concrete(template, ids)
            status, headers, value, raw = replay(t, d, srv, f"{method} {template}", method, path,
                                                 bodies.get((template, method)))
            t.check(status not in (404, 405), f"{method} {path} answers: {status} {raw[:200]!r}")


# ---------------------------------------------------------------------------------------
# (3) Real answers fit the document
# ---------------------------------------------------------------------------------------
def test_renders_and_problems(t, srv, d):
    scene = small_scene(24, 16)
    st, h, _, raw = replay(t, d, srv, "PNG", "POST", "/v1/renders", scene, want=200)
    t.equal(h.get("content-type"), "image/png", "PNG content type")
    st, h, _, raw = replay(t, d, srv, "EXR", "POST", "/v1/renders", scene,
                           {"Accept": "image/x-exr"}, want=200)
    t.equal(h.get("content-type"), "image/x-exr", "EXR content type")
    replay(t, d, srv, "EXR half", "POST", "/v1/renders?format=half", scene,
           {"Accept": "image/x-exr"}, want=200)
    st, h, p, _ = replay(t, d, srv, "request id", "POST", "/v1/renders", b"{", {
        "Content-Type": "application/json", "X-Request-Id": "abc-123"}, want=400)
    t.equal(h.get("x-request-id"), "abc-123", "X-Request-Id echoed")
    t.equal((p or {}).get("request_id"), "abc-123", "problem request_id")
    t.equal((p or {}).get("code"), "malformed_json", "400 malformed_json")
    st, h, p, _ = replay(t, d, srv, "400 bad_query", "POST", "/v1/renders?nope=1", scene, want=400)
    t.equal((p or {}).get("code"), "bad_query", "400 bad_query")
    replay(t, d, srv, "400 format with PNG", "POST", "/v1/renders?format=half", scene, want=400)
    replay(t, d, srv, "404 job", "GET", f"/v1/renders/{secrets.token_hex(16)}", want=404)
    replay(t, d, srv, "404 sweep", "GET", f"/v1/sweeps/{INSTANCE}-{secrets.token_hex(16)}/manifest.json",
           want=404)
    replay(t, d, srv, "404 file", "GET", "/nope.css", want=404)
    replay(t, d, srv, "405", "PUT", "/v1/renders", scene, want=405)
    replay(t, d, srv, "405 validate", "GET", "/v1/renders/validate", want=405)
    replay(t, d, srv, "406", "POST", "/v1/renders", scene, {"Accept": "text/html"}, want=406)
    replay(t, d, srv, "415", "POST", "/v1/renders", json.dumps(scene).encode(),
           {"Content-Type": "text/plain"}, want=415)
    bad = small_scene(24, 16)
    bad["materials"]["wax"]["g"] = 2
    st, h, p, _ = replay(t, d, srv, "422", "POST", "/v1/renders", bad, want=422)
    t.equal(((p or {}).get("errors") or [{}])[0].get("pointer"), "/materials/wax/g", "422 pointer")
    # 413 from Content-Length, before the body: the raw answer, then the connection closes.
    data = srv.raw(b"POST /v1/renders HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                   b"Content-Length: 999999999\r\n\r\n")
    st, h, raw = parse_raw_response(data)
    t.equal(st, 413, "413 from Content-Length")
    check_answer(t, d, "413", "POST", "/v1/renders", st, h, raw)
    replay(t, d, srv, "validate 204", "POST", "/v1/renders/validate", scene, want=204)
    replay(t, d, srv, "validate 422", "POST", "/v1/renders/validate", bad, want=422)
    replay(t, d, srv, "validate 415", "POST", "/v1/renders/validate", b"{}",
           {"Content-Type": "text/plain"}, want=415)
    for path in ("/livez", "/readyz", "/v1/info", "/v1/materials", "/metrics", "/openapi.json",
                 "/", "/app.js", "/style.css", "/v1/renders", "/v1/sweeps"):
        replay(t, d, srv, f"GET {path}", "GET", path, want=200)
        replay(t, d, srv, f"HEAD {path}", "HEAD", path, want=200)
    replay(t, d, srv, "metrics query", "GET", "/metrics?x=1", want=400)
    replay(t, d, srv, "openapi query", "GET", "/openapi.json?x=1", want=400)


def test_jobs(t, srv, d):
    """A slow job running, one queued, a full queue, the image before it is done, both kinds
    of cancel, events; then a job done, its image, its events, a discard and the 410."""
    t.check(wait_idle(srv), "nothing admitted before the queue is filled")
    rate = PtRate(srv)
    t.check(rate.ok, "pt rate measured")
    slow, _ = rate.scene(60)
    st, h, running, _ = replay(t, d, srv, "202 running", "POST", "/v1/renders", slow,
                               {"Prefer": "respond-async"}, want=202)
    a = (running or {}).get("links", {}).get("self", "")
    t.equal(h.get("location"), a, "Location is the job")
    t.check(a.startswith(f"/v1/renders/{INSTANCE}-"), f"the id names the instance: {a}")
    wait_state(srv, a, ("running", "done", "failed", "cancelled"))
    st, h, queued, _ = replay(t, d, srv, "202 queued", "POST", "/v1/renders", slow,
                              {"Prefer": "respond-async"}, want=202)
    b = (queued or {}).get("links", {}).get("self", "")
    replay(t, d, srv, "503 queue_full", "POST", "/v1/renders", small_scene(8, 8), want=503)
    replay(t, d, srv, "409 image", "GET", a + "/image", want=409)
    replay(t, d, srv, "status running", "GET", a, want=200)
    replay(t, d, srv, "status queued", "GET", b, want=200)
    replay(t, d, srv, "list", "GET", "/v1/renders", want=200)
    replay(t, d, srv, "events bad id", "GET", a + "/events?last_event_id=x", want=400)
    replay(t, d, srv, "DELETE queued 200", "DELETE", b, want=200)
    replay(t, d, srv, "DELETE running 202", "DELETE", a, want=202)
    job = wait_state(srv, a, ("cancelled", "done", "failed"))
    t.equal(job.get("state"), "cancelled", "the running job was cancelled")
    replay(t, d, srv, "status cancelled", "GET", a, want=200)
    replay(t, d, srv, "409 cancelled image", "GET", a + "/image", want=409)
    names = check_events(t, d, "events cancelled", a + "/events", read_events(srv, a + "/events"))
    t.equal(names[-1:], ["cancelled"], "the last event is cancelled")

    st, h, done, _ = replay(t, d, srv, "202 small", "POST", "/v1/renders", small_scene(24, 16),
                            {"Prefer": "respond-async"}, want=202)
    c = (done or {}).get("links", {}).get("self", "")
    t.equal(wait_state(srv, c, ("done", "failed", "cancelled")).get("state"), "done", "done")
    replay(t, d, srv, "status done", "GET", c, want=200)
    replay(t, d, srv, "image PNG", "GET", c + "/image", want=200)
    replay(t, d, srv, "image EXR half", "GET", c + "/image?format=half", None,
           {"Accept": "image/x-exr"}, want=200)
    replay(t, d, srv, "image 406", "GET", c + "/image", None, {"Accept": "text/plain"}, want=406)
    stream = read_events(srv, c + "/events")
    names = check_events(t, d, "events done", c + "/events", stream)
    t.equal(names[-1:], ["done"], "the last event is done")
    last = stream.events[-1].id if stream.events else "0"
    replay(t, d, srv, "events 204", "GET", c + "/events", None, {"Last-Event-ID": last}, want=204)
    replay(t, d, srv, "DELETE finished 204", "DELETE", c, want=204)
    replay(t, d, srv, "410", "GET", c, want=410)
    replay(t, d, srv, "410 image", "GET", c + "/image", want=410)
    replay(t, d, srv, "410 events", "GET", c + "/events", want=410)


def test_sweeps(t, srv, d):
    body = {"scene": small_scene(16, 16), "grid": {"/materials/wax/g": [0.2, 0.5]}}
    st, h, sweep, _ = replay(t, d, srv, "sweep 202", "POST", "/v1/sweeps", body, want=202)
    s = (sweep or {}).get("links", {}).get("self", "")
    t.equal(h.get("location"), s, "Location is the sweep")
    t.equal(wait_state(srv, s, ("done", "failed", "cancelled")).get("state"), "done", "sweep done")
    replay(t, d, srv, "sweep status", "GET", s, want=200)
    replay(t, d, srv, "sweep list", "GET", "/v1/sweeps", want=200)
    replay(t, d, srv, "manifest", "GET", s + "/manifest.json", want=200)
    st, h, _, raw = replay(t, d, srv, "sheet", "GET", s + "/sheet.png", want=200)
    t.equal(h.get("content-type"), "image/png", "sheet is a PNG")
    replay(t, d, srv, "variant image", "GET", s + "/images/1", want=200)
    replay(t, d, srv, "variant EXR", "GET", s + "/images/0?format=float", None,
           {"Accept": "image/x-exr"}, want=200)
    replay(t, d, srv, "variant 404", "GET", s + "/images/9", want=404)
    names = check_events(t, d, "sweep events", s + "/events", read_events(srv, s + "/events"))
    t.check("variant_start" in names and "variant_end" in names, f"variant events: {names}")
    replay(t, d, srv, "invalid sweep", "POST", "/v1/sweeps",
           {"scene": small_scene(16, 16), "variants": [{"/materials/wax/g": 2}]}, want=422)
    replay(t, d, srv, "sweep malformed", "POST", "/v1/sweeps", b"[", {"Content-Type": "application/json"},
           want=400)
    replay(t, d, srv, "sweep DELETE", "DELETE", s, want=204)
    replay(t, d, srv, "sweep 410", "GET", s + "/sheet.png", want=410)


# ---------------------------------------------------------------------------------------
# (4) Scenes against the Scene schema
# ---------------------------------------------------------------------------------------
def mutate(fn):
    scene = small_scene(24, 16)
    fn(scene)
    return scene


def set_in(pointer, value):
    def fn(scene):
        parts = pointer.split("/")[1:]
        at = scene
        for p in parts[:-1]:
            at = at[int(p)] if isinstance(at, list) else at[p]
        if isinstance(at, list):
            at[int(parts[-1])] = value
        else:
            at[parts[-1]] = value
    return fn


def drop(pointer):
    def fn(scene):
        parts = pointer.split("/")[1:]
        at = scene
        for p in parts[:-1]:
            at = at[int(p)] if isinstance(at, list) else at[p]
        del at[parts[-1]]
    return fn


def both(*fns):
    def fn(scene):
        for f in fns:
            f(scene)
    return fn


WAX = "/materials/wax"
MESH = {"shape": "mesh", "asset": "octahedron.glb", "material": "wax"}
# Scenes the parser refuses for a reason a schema can state (after tests/unit_scene_json.c's
# bad_cases): the schema must refuse them too.
REFUSED = [
    ("unknown top-level key", set_in("/colour", 1)),
    ("unknown camera key", set_in("/camera/fov2", 30)),
    ("fov a string", set_in("/camera/fov", "30")),
    ("position an object", set_in("/camera/position", {"x": 0})),
    ("up of 2 elements", set_in("/camera/up", [0, 1])),
    ("up zero", set_in("/camera/up", [0, 0, 0])),
    ("fov 0", set_in("/camera/fov", 0)),
    ("fov 180", set_in("/camera/fov", 180)),
    ("width 0", set_in("/camera/width", 0)),
    ("width 100000", set_in("/camera/width", 100000)),
    ("height 256.5", set_in("/camera/height", 256.5)),
    ("camera missing", drop("/camera")),
    ("camera fov missing", drop("/camera/fov")),
    ("materials an array", set_in("/materials", [])),
    ("materials missing", drop("/materials")),
    ("objects an object", set_in("/objects", {})),
    ("objects missing", drop("/objects")),
    ("lights missing", drop("/lights")),
    ("lights an object", set_in("/lights", {})),
    ("object a number", set_in("/objects/0", 42)),
    ("unknown diffuse key", set_in("/materials/floor/color", 1)),
    ("unknown medium key", set_in(WAX + "/sigma_t", 1)),
    ("reflectance a string", set_in("/materials/floor/reflectance", "red")),
    ("reflectance above 1", set_in("/materials/floor/reflectance", [0.5, 0.5, 1.01])),
    ("diffuse without reflectance", drop("/materials/floor/reflectance")),
    ("material without type", drop(WAX + "/type")),
    ("material type glass", set_in(WAX + "/type", "glass")),
    ("sigma_a negative", set_in(WAX, {"type": "medium", "sigma_s": [1, 1, 1], "sigma_a": [-1, 0, 0]})),
    ("sigma_s negative", set_in(WAX, {"type": "medium", "sigma_s": -0.5, "sigma_a": 1})),
    ("albedo 1.2", set_in(WAX, {"type": "medium", "albedo": 1.2, "mfp": 1})),
    ("albedo channel 1.2", set_in(WAX, {"type": "medium", "albedo": [0.5, 1.2, 0.5], "mfp": 1})),
    ("mfp 0", set_in(WAX, {"type": "medium", "albedo": 0.5, "mfp": 0})),
    ("mfp channel negative", set_in(WAX, {"type": "medium", "albedo": 0.5, "mfp": [1, -1, 1]})),
    ("g 1", set_in(WAX, {"type": "medium", "preset": "milk", "g": 1})),
    ("g -1", set_in(WAX, {"type": "medium", "preset": "milk", "g": -1})),
    ("ior 0.9", set_in(WAX, {"type": "medium", "preset": "milk", "ior": 0.9})),
    ("scale 0", set_in(WAX, {"type": "medium", "preset": "milk", "scale": 0})),
    ("both forms", set_in(WAX, {"type": "medium", "sigma_s": 1, "sigma_a": 1, "albedo": 0.5, "mfp": 1})),
    ("sigma_a with mfp", set_in(WAX, {"type": "medium", "sigma_a": 1, "mfp": 1})),
    ("sigma_s alone", set_in(WAX, {"type": "medium", "sigma_s": 1})),
    ("preset and sigma_s alone", set_in(WAX, {"type": "medium", "preset": "milk", "sigma_s": 1})),
    ("albedo alone", set_in(WAX, {"type": "medium", "albedo": 0.5})),
    ("no coefficients", set_in(WAX, {"type": "medium", "g": 0.5})),
    ("unknown preset", set_in(WAX, {"type": "medium", "preset": "jade"})),
    ("material name of 64 bytes", set_in("/materials/" + "a" * 64, {"type": "diffuse", "reflectance": 0.5})),
    ("empty material name", set_in("/materials/", {"type": "diffuse", "reflectance": 0.5})),
    ("object material a number", set_in("/objects/0/material", 7)),
    ("object without material", drop("/objects/0/material")),
    ("object without shape", drop("/objects/0/shape")),
    ("shape torus", set_in("/objects/0/shape", "torus")),
    ("unknown sphere key", set_in("/objects/0/radious", 2)),
    ("radius 0", set_in("/objects/0/radius", 0)),
    ("radius -1", set_in("/objects/0/radius", -1)),
    ("radius too large for a float", set_in("/objects/0/radius", 1e300)),
    ("plane normal zero", set_in("/objects/1/normal", [0, 0, 0])),
    ("mesh with two sources", set_in("/objects/0", dict(MESH, uri="data:model/gltf-binary;base64,AAAA"))),
    ("mesh without a source", set_in("/objects/0", {"shape": "mesh", "material": "wax"})),
    ("mesh uri not data:", set_in("/objects/0", {"shape": "mesh", "uri": "http://example.com/a.glb", "material": "wax"})),
    ("mesh data uri not base64", set_in("/objects/0", {"shape": "mesh", "uri": "data:model/gltf-binary,AAAA", "material": "wax"})),
    ("mesh glb_base64 not base64", set_in("/objects/0", {"shape": "mesh", "glb_base64": "Z2x*RgI=", "material": "wax"})),
    ("mesh asset a path", set_in("/objects/0", dict(MESH, asset="../octahedron.glb"))),
    ("mesh asset hidden", set_in("/objects/0", dict(MESH, asset=".octahedron.glb"))),
    ("mesh transform shear", set_in("/objects/0", dict(MESH, transform={"shear": 1}))),
    ("mesh transform scale 0", set_in("/objects/0", dict(MESH, transform={"scale": [1, 0, 1]}))),
    ("light direction zero", set_in("/lights/0/direction", [0, 0, 0])),
    ("irradiance negative", set_in("/lights/0/irradiance", [1, 1, -1])),
    ("unknown light key", set_in("/lights/0/color", 1)),
    ("sphere light radius 0", set_in("/lights/0", {"type": "sphere", "center": [0, 3, 0], "radius": 0, "radiance": 1})),
    ("two environments", set_in("/lights/0", {"type": "environment", "radiance": 1})),
    ("light type spot", set_in("/lights/0", {"type": "spot"})),
    ("light without type", set_in("/lights/0", {"direction": [0, -1, 0]})),
    ("render an array", set_in("/render", [])),
    ("unknown render key", set_in("/render/sampler", "sobol")),
    ("spp true", set_in("/render/spp", True)),
    ("spp 0", set_in("/render/spp", 0)),
    ("spp 5000", set_in("/render/spp", 5000)),
    ("spp 2.5", set_in("/render/spp", 2.5)),
    ("seed -1", set_in("/render/seed", -1)),
    ("seed 2^32", set_in("/render/seed", 4294967296)),
    ("seed 1e20", set_in("/render/seed", 99999999999999999999)),
    ("max_depth 0", set_in("/render/max_depth", 0)),
    ("max_depth 65", set_in("/render/max_depth", 65)),
    ("light_samples 0", set_in("/render/light_samples", 0)),
    ("light_samples 65", set_in("/render/light_samples", 65)),
    ("light_samples 1.5", set_in("/render/light_samples", 1.5)),
    ("adaptive_spp -1", set_in("/render/adaptive_spp", -1)),
    ("adaptive_spp 65", set_in("/render/adaptive_spp", 65)),
    ("adaptive_spp a string", set_in("/render/adaptive_spp", "2")),
    ("exposure 100", set_in("/render/exposure", 100)),
    ("method magic", set_in("/render/method", "magic")),
    ("components a string", set_in("/render/components", "surface")),
    ("components empty", set_in("/render/components", [])),
    ("component twice", set_in("/render/components", ["surface", "surface"])),
    ("component glow", set_in("/render/components", ["surface", "glow"])),
    ("component a number", set_in("/render/components", ["surface", 3])),
    ("gather_levels 5", set_in("/render/gather_levels", 5)),
    ("gather_levels 1.5", set_in("/render/gather_levels", 1.5)),
    ("gather_tolerance -0.1", set_in("/render/gather_tolerance", -0.1)),
    ("gather_camera_samples 4097", set_in("/render/gather_camera_samples", 4097)),
    ("single_levels 5", set_in("/render/single_levels", 5)),
    ("single_tolerance 2", set_in("/render/single_tolerance", 2)),
    ("vrl_beams finite", set_in("/render/vrl_beams", "finite")),
    ("vrl_beams true", set_in("/render/vrl_beams", True)),
    ("vrl_beams bounded with dipole", set_in("/render", {"method": "dipole", "components": ["double", "multiple"], "vrl_beams": "bounded"})),
    ("max_scatter without pt", set_in("/render/max_scatter", 2)),
    ("max_scatter without method", set_in("/render", {"components": ["surface"], "max_scatter": 2})),
    ("dipole double alone", set_in("/render", {"method": "dipole", "components": ["surface", "double"]})),
    ("deadline_ms 0", set_in("/render/deadline_ms", 0)),
    ("cull_solid_angle 13", set_in("/render/cull_solid_angle", 13)),
    ("vrls 0", set_in("/render/vrls", 0)),
    ("accumulation sloppy", set_in("/render/accumulation", "sloppy")),
    ("tables blended", set_in("/render/tables", "blended")),
    ("tables interpolated with pt", set_in("/render", {"method": "pt", "components": ["surface"], "tables": "interpolated"})),
    ("version 2", set_in("/version", 2)),
]
# Refused by the parser for reasons a JSON Schema cannot state (docs in the Scene schema's
# description): the schema accepts them, the server refuses them.
BEYOND_SCHEMA = [
    ("look_at equals position", set_in("/camera/look_at", [0, 2, 6])),
    ("up parallel to the view", set_in("/camera", {"position": [0, 2, 0], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 30, "width": 8, "height": 8})),
    ("width x height over the limit", set_in("/camera", {"position": [0, 2, 6], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 30, "width": 8192, "height": 8192})),
    ("box max not above min", set_in("/objects/0", {"shape": "box", "min": [0, 0, 0], "max": [1, 0, 1], "material": "wax"})),
    ("unknown material", set_in("/objects/0/material", "marble")),
    ("nn medium with g < 0", both(set_in(WAX + "/g", -0.5),
                                  set_in("/render", {"method": "nn", "components": ["single"]}))),
    ("scaled coefficients overflow", set_in(WAX, {"type": "medium", "albedo": 0.5, "mfp": 1e-38, "scale": 1e10})),
    ("vrls over the service's --max-vrls", set_in("/render/vrls", MAX_VRLS + 1)),
    ("adaptive_spp at one sample per pixel", set_in("/render", {"spp": 1, "adaptive_spp": 2})),
]
ACCEPTED = [
    ("grey colours", set_in("/materials/floor/reflectance", 0.5)),
    ("an integer written 16.0", set_in("/camera/width", 16.0)),
    ("a preset with albedo alone", set_in(WAX, {"type": "medium", "preset": "candle", "albedo": [0.8, 0.9, 0.85]})),
    ("version 1", set_in("/version", 1)),
    ("max_scatter with pt", set_in("/render", {"method": "pt", "components": ["surface"], "max_scatter": 2})),
    ("adaptive_spp 0.5 at 4 spp", set_in("/render", {"spp": 4, "adaptive_spp": 0.5})),
    ("adaptive_spp 0 at one sample per pixel", set_in("/render", {"spp": 1, "adaptive_spp": 0})),
    ("dipole with both gathered orders", set_in("/render", {"method": "dipole", "components": ["surface", "double", "multiple"]})),
    ("a mesh by asset", set_in("/objects/0", dict(MESH, transform={"scale": 0.5, "rotate_deg": [0, 45, 0]}))),
    ("one environment among others", set_in("/lights/0", {"type": "point", "position": [0, 3, 0], "intensity": 5})),
]


def scene_files():
    out = []
    for folder in ("scenes", os.path.join("scenes", "bench")):
        for name in sorted(os.listdir(os.path.join(SOURCE, folder))):
            # bench.json is the benchmark's index of scenes, not a scene.
            if name.endswith(".json") and name != "bench.json":
                out.append(os.path.join(folder, name))
    return out


def test_shipped_scenes(t, srv, d):
    files = scene_files()
    t.check(len(files) >= 10, f"scene files: {files}")
    scene = d.schema("Scene")
    for path in files:
        with open(os.path.join(SOURCE, path), encoding="utf-8") as f:
            doc = json.load(f)
        errs = d.errors(scene, doc)
        t.check(not errs, f"{path} validates against Scene: {errs[:3]}")
        if not path.startswith(os.path.join("scenes", "bench")):  # bench meshes are made by bench
            status, _, raw = srv.render(doc, path="/v1/renders/validate")
            t.equal(status, 204, f"{path}: the server accepts it too {raw[:200]!r}")


def test_refused_scenes(t, srv, d):
    scene = d.schema("Scene")
    for what, fn in REFUSED:
        doc = mutate(fn)
        t.check(d.errors(scene, doc), f"{what}: the schema refuses it")
        status, _, raw = srv.render(doc, path="/v1/renders/validate")
        t.equal(status, 422, f"{what}: the server refuses it {raw[:200]!r}")
    # Numbers past a double, duplicate keys: only as text.
    texts = [("1e999", json.dumps(small_scene(24, 16)).replace('"fov": 30', '"fov": 1e999'))]
    for what, text in texts:
        t.check(d.errors(scene, json.loads(text)), f"{what}: the schema refuses it")
        status, _, raw = srv.render(text.encode(), path="/v1/renders/validate")
        t.equal(status, 422, f"{what}: the server refuses it {raw[:200]!r}")
    for what, fn in BEYOND_SCHEMA:
        doc = mutate(fn)
        t.check(not d.errors(scene, doc), f"{what}: beyond the schema (update the Scene "
                                          "description if the schema now says it)")
        status, _, raw = srv.render(doc, path="/v1/renders/validate")
        t.equal(status, 422, f"{what}: the server refuses it {raw[:200]!r}")
    duplicate = json.dumps(small_scene(24, 16)).replace('"fov": 30', '"fov": 30, "fov": 40')
    status, _, _ = srv.render(duplicate.encode(), path="/v1/renders/validate")
    t.equal(status, 422, "a duplicate key: the server refuses it (JSON Schema sees one value)")
    for what, fn in ACCEPTED:
        doc = mutate(fn)
        t.check(not d.errors(scene, doc), f"{what}: the schema accepts it: {d.errors(scene, doc)[:3]}")
        status, _, raw = srv.render(doc, path="/v1/renders/validate")
        t.equal(status, 204, f"{what}: the server accepts it {raw[:200]!r}")


def test_sweep_bodies(t, srv, d):
    sweep = d.schema("SweepRequest")
    good = [{"scene": small_scene(16, 16), "variants": [{"/materials/wax/g": 0.5}, {}]},
            {"scene": small_scene(16, 16), "grid": {"/materials/wax/g": [0.2, 0.5]}}]
    for body in good:
        t.check(not d.errors(sweep, body), f"sweep body accepted: {d.errors(sweep, body)[:3]}")
    bad = [("unknown key", {"scene": small_scene(), "variants": [{}], "colour": 1}),
           ("no scene", {"variants": [{}]}),
           ("both variants and grid", {"scene": small_scene(), "variants": [{}], "grid": {"/render/spp": [1]}}),
           ("neither", {"scene": small_scene()}),
           ("no variants", {"scene": small_scene(), "variants": []}),
           ("a variant not an object", {"scene": small_scene(), "variants": [3]}),
           ("an empty grid", {"scene": small_scene(), "grid": {}}),
           ("a grid entry not a list", {"scene": small_scene(), "grid": {"/render/spp": 1}}),
           ("a grid entry empty", {"scene": small_scene(), "grid": {"/render/spp": []}}),
           ("257 variants", {"scene": small_scene(), "variants": [{}] * 257})]
    for what, body in bad:
        t.check(d.errors(sweep, body), f"sweep {what}: the schema refuses it")
        status, _, value, raw = replay(t, d, srv, f"sweep {what}", "POST", "/v1/sweeps", body)
        t.equal(status, 422, f"sweep {what}: the server refuses it {raw[:200]!r}")


# ---------------------------------------------------------------------------------------
def make_jobs(srv):
    """A finished render and sweep to probe the job routes with, and a second of each to
    discard (DELETE)."""
    out = {}
    for key in ("keep", "discard"):
        ids = {}
        st, _, job, _ = post_json(srv, "/v1/renders", small_scene(16, 16), {"Prefer": "respond-async"})
        ids["render"] = (job or {}).get("id", INSTANCE + "-" + "0" * 32)
        st, _, job, _ = post_json(srv, "/v1/sweeps", {"scene": small_scene(16, 16), "variants": [{}]})
        ids["sweep"] = (job or {}).get("id", INSTANCE + "-" + "0" * 32)
        for kind, jid in ids.items():
            wait_state(srv, f"/v1/{kind}s/{jid}", ("done", "failed", "cancelled"))
        out[key] = ids
    return out["keep"], out["discard"]


def main():
    t = Checks()
    assets = os.path.join(SOURCE, "scenes", "assets")
    with Server("--queue", "2", "--max-body", str(MAX_BODY), "--assets", assets,
                "--instance", INSTANCE, "--max-vrls", str(MAX_VRLS)) as srv:
        status, _, raw = srv.request("GET", "/openapi.json")
        try:
            d = Doc(json.loads(raw))
        except (ValueError, KeyError) as e:
            print(f"FAIL: GET /openapi.json is not a document ({status}, {e}): {raw[:300]!r}",
                  file=sys.stderr)
            return 1
        jobs, discard = make_jobs(srv)
        t.run(test_document_is_valid, srv, d)
        t.run(test_version_and_enums_agree_with_sources, srv, d)
        t.run(test_every_route_is_described, srv, d, jobs)
        t.run(test_every_description_is_answered, srv, d, jobs, discard)
        t.run(test_renders_and_problems, srv, d)
        t.run(test_jobs, srv, d)
        t.run(test_sweeps, srv, d)
        t.run(test_shipped_scenes, srv, d)
        t.run(test_refused_scenes, srv, d)
        t.run(test_sweep_bodies, srv, d)
        t.check(srv.alive(), "the server is still up")
        code = srv.stop()
        t.check(srv.exited_cleanly(code), f"clean exit after SIGTERM (status {code})")
    return t.report()


if __name__ == "__main__":
    sys.exit(main())
