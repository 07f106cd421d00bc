// Drives a running netem through toxiproxy's own Node client (toxiproxy-node-client 4.1.0):
// list, get, disable/enable, every toxic netem supports (added, updated, removed), reset, and
// the refusals a test suite meets (populate/createProxy: 405; moving a proxy: 409; no token: 401).
//
// Usage: node drive.js BASE_URL
//   BASE_URL carries the run's token as its path (http://ADDR/token/TOKEN): this client uses
//   fetch, which refuses credentials in a URL, and cannot send headers of its own.
// Prints one JSON line per phase: {"phase", "link", "before", "after", "removed_before",
// "removed_after", "start", "first", "last", "later", "again"} — the steps netem reported just before
// and just after the phase's toxic (or cut) went on and came off, and the link's GET /links rows
// around them; tests/toxiproxy_client.rs checks links.csv in those windows, and the counters that
// links.csv leaves out (writes, connections, toxics) in the rows.
// Exits non-zero on the first thing that is not as expected.
"use strict";

const assert = require("node:assert/strict");
const { Toxiproxy, ToxiproxyError } = require("toxiproxy-node-client");

const base = process.argv[2];
if (!base) {
  console.error("usage: node drive.js BASE_URL");
  process.exit(2);
}
const toxiproxy = new Toxiproxy(base);

// The step netem last reported (its own GET /links, through the same base URL).
async function step() {
  const res = await fetch(`${base}/links`);
  assert.equal(res.status, 200, `GET /links: ${res.status}`);
  const rows = await res.json();
  return rows[0].step;
}

// Waits until netem has reported `n` more steps (at most 120 s).
async function steps(n) {
  const until = (await step()) + n;
  const deadline = Date.now() + 120000;
  while ((await step()) < until) {
    assert.ok(Date.now() < deadline, `the run did not reach step ${until}`);
    await new Promise((r) => setTimeout(r, 20));
  }
}

// Expects `p` to fail with HTTP status `status` (the client's error says only the status).
async function refused(p, status, what) {
  await assert.rejects(p, (e) => {
    assert.ok(e instanceof ToxiproxyError, `${what}: ${e}`);
    assert.match(e.message, new RegExp(`status code ${status}`), what);
    return true;
  });
}

// The link's row as netem reports it now (GET /links: its counters and toxics).
async function row(link) {
  const res = await fetch(`${base}/links`);
  assert.equal(res.status, 200, `GET /links: ${res.status}`);
  const [a, b] = link.slice(1).split("-r").map(Number);
  const r = (await res.json()).find((x) => x.a === a && x.b === b);
  assert.ok(r, `no row for ${link}`);
  return r;
}

// Runs `on` (puts a fault on), waits `hold` steps, runs `off`; prints the phase's steps and the
// link's rows just before `on` (start), one step after it (first), just before `off` (last) and
// two steps after (later). A fault that ends connections (`reconnects`) also gets the row once
// the robots connected again (again; at most 60 steps after `later`: a reconnection takes
// wall time, which a loaded machine stretches over more steps).
async function phase(name, link, hold, on, off, reconnects = false) {
  const start = await row(link);
  const before = await step();
  const result = await on();
  const after = await step();
  await steps(1);
  const first = await row(link);
  await steps(hold);
  const last = await row(link);
  const removedBefore = await step();
  await off(result);
  const removedAfter = await step();
  await steps(2);
  const later = await row(link);
  let again = null;
  if (reconnects) {
    const until = (await step()) + 60;
    again = later;
    while (again.established_total <= start.established_total && (await step()) < until) {
      await new Promise((r) => setTimeout(r, 20));
      again = await row(link);
    }
  }
  console.log(JSON.stringify({
    phase: name, link, before, after,
    removed_before: removedBefore, removed_after: removedAfter,
    start, first, last, later, again,
  }));
  await steps(2);
}

async function main() {
  // No token: every call is 401.
  const url = new URL(base);
  const bare = new Toxiproxy(`${url.protocol}//${url.host}`);
  await refused(bare.getAll(), 401, "without the token");

  assert.match(await toxiproxy.getVersion(), /toxiproxy API/);
  const all = await toxiproxy.getAll();
  assert.deepEqual(Object.keys(all).sort(), ["r0-r1", "r0-r2", "r1-r2"]);
  const p01 = await toxiproxy.get("r0-r1");
  assert.equal(p01.name, "r0-r1");
  assert.equal(p01.enabled, true);
  const p02 = await toxiproxy.get("r0-r2");
  const p12 = await toxiproxy.get("r1-r2");

  // Proxies are the scenario's pairs: a test suite's populate()/createProxy() is refused.
  const body = { name: "db", listen: "127.0.0.1:0", upstream: "127.0.0.1:5432" };
  await refused(toxiproxy.populate([body]), 405, "populate");
  await refused(toxiproxy.createProxy(body), 405, "createProxy");
  // An update that would move the proxy is refused, and changes nothing.
  await refused(
    p01.update({ enabled: false, listen: "127.0.0.1:1", upstream: p01.upstream }),
    409, "update with another listen");
  assert.equal((await toxiproxy.get("r0-r1")).enabled, true);

  await steps(5);

  // disable / enable, as the client does it: the whole proxy back with enabled changed.
  await phase("disable", "r0-r1", 10,
    async () => {
      const p = await p01.update({ enabled: false, listen: p01.listen, upstream: p01.upstream });
      assert.equal(p.enabled, false);
      return p;
    },
    async (p) => {
      const back = await p.update({ enabled: true, listen: p.listen, upstream: p.upstream });
      assert.equal(back.enabled, true);
    });

  // latency, updated while on (toxiproxy's update merges attributes), then removed.
  await phase("latency", "r0-r2", 8,
    async () => {
      const t = await p02.addToxic({
        name: "lag", type: "latency", stream: "downstream", toxicity: 1,
        attributes: { latency: 3000, jitter: 0 },
      });
      const up = await p02.addToxic({
        name: "lag_up", type: "latency", stream: "upstream", toxicity: 1,
        attributes: { latency: 1000, jitter: 0 },
      });
      const changed = await up.update({ attributes: { latency: 3000 } });
      assert.equal(changed.attributes.latency, 3000);
      assert.equal((await p02.getToxic("lag")).attributes.latency, 3000);
      return [t, changed];
    },
    async (ts) => { for (const t of ts) await t.remove(); });

  // bandwidth: 1 KB/s both ways, below the run's own rate.
  await phase("bandwidth", "r1-r2", 15,
    async () => Promise.all(["upstream", "downstream"].map((stream) => p12.addToxic({
      name: `slow_${stream}`, type: "bandwidth", stream, toxicity: 1, attributes: { rate: 1 },
    }))),
    async (ts) => { for (const t of ts) await t.remove(); });

  // slicer: writes of 16 ± 4 bytes, 10 µs apart, both ways.
  await phase("slicer", "r0-r1", 10,
    async () => Promise.all(["upstream", "downstream"].map((stream) => p01.addToxic({
      name: `slices_${stream}`, type: "slicer", stream, toxicity: 1,
      attributes: { average_size: 16, size_variation: 4, delay: 10 },
    }))),
    async (ts) => { for (const t of ts) await t.remove(); });

  // slow_close: listed with its delay, then updated and removed.
  await phase("slow_close", "r0-r1", 3,
    async () => {
      const t = await p01.addToxic({
        name: "linger", type: "slow_close", stream: "downstream", toxicity: 1,
        attributes: { delay: 2000 },
      });
      assert.equal(t.attributes.delay, 2000);
      const changed = await t.update({ attributes: { delay: 500 } });
      assert.equal(changed.attributes.delay, 500);
      return changed;
    },
    async (t) => t.remove());

  // timeout 0: a blackhole — the link stays up and carries nothing.
  await phase("timeout", "r0-r2", 10,
    async () => p02.addToxic({
      name: "hole", type: "timeout", stream: "downstream", toxicity: 1,
      attributes: { timeout: 0 },
    }),
    async (t) => t.remove());

  // reset_peer and limit_data close connections; the robots reconnect.
  await phase("reset_peer", "r1-r2", 5,
    async () => p12.addToxic({
      name: "rst", type: "reset_peer", stream: "downstream", toxicity: 1,
      attributes: { timeout: 500 },
    }),
    async (t) => t.remove(), true);
  await phase("limit_data", "r0-r1", 8,
    async () => p01.addToxic({
      name: "cap", type: "limit_data", stream: "downstream", toxicity: 1,
      attributes: { bytes: 3000 },
    }),
    async (t) => t.remove(), true);

  // reset: a cut and two toxics, all gone at once.
  await phase("reset", "r0-r2", 4,
    async () => {
      await p02.update({ enabled: false, listen: p02.listen, upstream: p02.upstream });
      await p01.addToxic({ name: "a", type: "latency", stream: "upstream", toxicity: 1,
        attributes: { latency: 100 } });
      await p12.addToxic({ name: "b", type: "slicer", stream: "upstream", toxicity: 1,
        attributes: { average_size: 100 } });
    },
    async () => {
      await toxiproxy.reset();
      const after = await toxiproxy.getAll();
      for (const name of Object.keys(after)) {
        assert.equal(after[name].enabled, true, name);
        const res = await fetch(`${base}/proxies/${name}/toxics`);
        assert.deepEqual(await res.json(), [], name);
      }
    });
}

main().catch((e) => {
  console.error(e && e.stack ? e.stack : String(e));
  process.exit(1);
});
