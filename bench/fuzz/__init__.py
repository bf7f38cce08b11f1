"""Fuzz and fault tool: random and mutated frames against ``robot-server`` and the sans-I/O decoder.

A command run from the repository's root; prints one table and exits 1 if any failure count is
non-zero::

    python -m bench.fuzz            # both profiles, 1,000,000 frames each, then 1,000,000 through the decoder
    python -m bench.fuzz --profile generic --frames 20000 --decoder-frames 20000   # a quick look
    python -m bench.fuzz --server-args='--byte-order auto'          # more robot-server arguments
    python -m bench.fuzz --profile motoros --host 127.0.0.1 --motion-port 50240 --state-port 50241 \\
        --io-port 50242 --server-log server.log --server-pid 1234      # a server that is already running

Each module has one part of the tool and says, in its docstring, what it does and what it counts:

* :mod:`.protocol`: the header, the types and their layouts, frames built and read with :mod:`struct`;
* :mod:`.safety`: what is never sent (a valid motion command), and the model of the server's
  framing that checks every frame the server can cut before a byte is written;
* :mod:`.generator`: the frames (a corpus, random fields, mutations, broken framing);
* :mod:`.decoder`: the decoder run, in process;
* :mod:`.server`: a profile's server run: the server started (or found), fuzzed, stopped, its log
  read; :mod:`.run` the run in progress (fuzz connections, probe, state monitor, RSS) and
  :mod:`.connection` a fuzz connection's client side;
* :mod:`.report`: what counts as a failure, the table and the details below it;
* :mod:`.cli`: the command line.

Targets: at least 1,000,000 frames per profile with 0 crashes, 0 hangs, 0 tracebacks, 0 motion and
an RSS growth of at most 5 MB; at least 1,000,000 frames through the decoder with documented errors
only.

The names below are the tool's library, as its tests use it (``from bench import fuzz``).
"""

from __future__ import annotations

from .cli import main, options_from, parser
from .decoder import DecoderReport, fuzz_decoder
from .generator import Generator, load_corpus
from .protocol import HEADER, MAX_LENGTH, MOTION_TYPES, MOTO_COMMANDS, PING, frame_of, ping_request
from .report import HANG_AFTER, PortStats, ProfileReport, decoder_details, details, table
from .run import FuzzRun, Options, Target, rss_mb
from .safety import PLAUSIBLE, Shadow, poison_bytes, unsafe_reason
from .server import fuzz_server, start_server

__all__ = [
    "HANG_AFTER",
    "HEADER",
    "MAX_LENGTH",
    "MOTION_TYPES",
    "MOTO_COMMANDS",
    "PING",
    "PLAUSIBLE",
    "DecoderReport",
    "FuzzRun",
    "Generator",
    "Options",
    "PortStats",
    "ProfileReport",
    "Shadow",
    "Target",
    "decoder_details",
    "details",
    "frame_of",
    "fuzz_decoder",
    "fuzz_server",
    "load_corpus",
    "main",
    "options_from",
    "parser",
    "ping_request",
    "poison_bytes",
    "rss_mb",
    "start_server",
    "table",
    "unsafe_reason",
]
