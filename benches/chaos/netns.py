"""The harness's network: one network namespace per host (the servers, the client, each API
replica and each worker), each with one veth into a bridge that lives in a namespace of its own,
so nothing is added to the machine's own network and every address (10.237.0.0/24) exists only
inside these namespaces. Partitions are nftables rules inside one host's namespace."""

import subprocess

SUBNET = "10.237.0"


def run(*argv, stdin=None, check=True):
    return subprocess.run(argv, input=stdin, text=True, capture_output=True, check=check)


class Network:
    def __init__(self, prefix, hosts):
        self.prefix = prefix
        self.hosts = list(hosts)
        self.ips = {host: f"{SUBNET}.{10 + i}" for i, host in enumerate(self.hosts)}

    def ns(self, host):
        return f"{self.prefix}-{host}"

    def exec(self, host):
        """The argv prefix that runs a command inside `host`'s namespace."""
        return ["ip", "netns", "exec", self.ns(host)]

    def create(self):
        bridge = self.ns("net")
        run("ip", "netns", "add", bridge)
        run("ip", "-n", bridge, "link", "add", "br0", "type", "bridge")
        run("ip", "-n", bridge, "link", "set", "br0", "up")
        for i, host in enumerate(self.hosts):
            ns = self.ns(host)
            run("ip", "netns", "add", ns)
            port = f"p{i}"
            run("ip", "link", "add", "eth0", "netns", ns, "type", "veth",
                "peer", "name", port, "netns", bridge)
            run("ip", "-n", bridge, "link", "set", port, "master", "br0", "up")
            run("ip", "-n", ns, "addr", "add", f"{self.ips[host]}/24", "dev", "eth0")
            run("ip", "-n", ns, "link", "set", "eth0", "up")
            run("ip", "-n", ns, "link", "set", "lo", "up")

    def destroy(self):
        """Kills whatever still runs in the namespaces (all of it started by this harness) and
        deletes them."""
        for host in self.hosts + ["net"]:
            ns = self.ns(host)
            pids = run("ip", "netns", "pids", ns, check=False).stdout.split()
            for pid in pids:
                run("kill", "-9", pid, check=False)
            run("ip", "netns", "del", ns, check=False)

    def block(self, host, peer_ip, port, mode="drop", inbound=False):
        """Cuts `host` off from `peer_ip:port`: `drop` loses packets (a partition: connections
        hang), `reject` answers with a reset (a stopped server: connections are refused).
        `inbound` applies it to connections made to `host` on `port` instead (from anyone)."""
        if inbound:
            verdict = "reject with tcp reset" if mode == "reject" else "drop"
            rules = (f" chain in {{\n  type filter hook input priority 0\n"
                     f"  tcp dport {port} {verdict}\n }}\n")
        else:
            out_verdict = "reject with tcp reset" if mode == "reject" else "drop"
            rules = (f" chain out {{\n  type filter hook output priority 0\n"
                     f"  ip daddr {peer_ip} tcp dport {port} {out_verdict}\n }}\n"
                     f" chain in {{\n  type filter hook input priority 0\n"
                     f"  ip saddr {peer_ip} tcp sport {port} drop\n }}\n")
        run(*self.exec(host), "nft", "-f", "-", stdin=f"table inet chaos {{\n{rules}}}\n")

    def heal(self, host):
        run(*self.exec(host), "nft", "delete", "table", "inet", "chaos", check=False)


def assert_isolated():
    """Refuses to go on unless this process is inside one of the harness's namespaces: no
    default route, and no address outside loopback and the harness's subnet, so no request
    of the harness can leave the machine."""
    routes = run("ip", "route", "show", "default").stdout.strip()
    addresses = run("ip", "-o", "-4", "addr", "show").stdout.split("\n")
    foreign = [line for line in addresses if line.strip()
               and " 127." not in line and f" {SUBNET}." not in line]
    if routes or foreign:
        raise SystemExit(f"chaos: not inside the harness's network namespace "
                         f"(default route {routes!r}, addresses {foreign})")
