"""The distance node in a process whose Zenoh session is closed and opened again on signals: the network
partition of ``test_nodes_faults.py``, simulated by closing the session while the process lives on.

``python tests/partition_node.py CELL LOG``: SIGUSR1 closes the node's session (the node's own clean close:
tokens undeclared, links closed), SIGUSR2 opens a new one (a new Zenoh id, found again by the peers'
connection retries), SIGTERM ends. Each close and open is printed as a JSON line with its wall time.
"""

from __future__ import annotations

import json
import signal
import sys
import threading
import time

from depthguard.io.cellfile import read_cell
from depthguard.nodes.distance import run_distance_node


class _Flag:
    def __init__(self) -> None:
        self.ev = threading.Event()

    def __bool__(self) -> bool:
        return self.ev.is_set()


def main(cell_path: str, log: str) -> None:
    cell = read_cell(cell_path)
    term, reopen = threading.Event(), threading.Event()
    flag = _Flag()

    def on_term(*_):
        term.set()
        flag.ev.set()
        reopen.set()

    signal.signal(signal.SIGUSR1, lambda *_: flag.ev.set())
    signal.signal(signal.SIGUSR2, lambda *_: reopen.set())
    signal.signal(signal.SIGTERM, on_term)
    while True:
        print(json.dumps({"ev": "open", "t": time.time()}), flush=True)
        run_distance_node(cell, stop=flag, log=log)
        print(json.dumps({"ev": "closed", "t": time.time()}), flush=True)
        reopen.wait()
        if term.is_set():
            return
        reopen.clear()
        flag.ev.clear()


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
