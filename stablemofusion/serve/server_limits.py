"""Every limit of `smf serve` in one place (docs/serve.md lists them): sizes, counts, ranges and timeouts."""

from __future__ import annotations

from ..core.limits import MAX_SECONDS

# request bodies (enforced while reading, for every transfer encoding: serve/guard.py)
MAX_BODY_BYTES = 16 * 1024  # a JSON request
MAX_UPLOAD_BYTES = 16 * 1024 * 1024  # a dropped .bvh / .npy (POST /v1/convert)
UPLOAD_BUDGET_BYTES = 4 * MAX_UPLOAD_BYTES  # uploads held at once, all clients together (their declared or largest
# size is reserved before a byte is read); an upload past it gets 503 at once
BODY_TIMEOUT_S = 30.0  # the whole body must arrive within this
# connections (uvicorn settings: serve/server.py)
HEADER_TIMEOUT_S = 10.0  # a connection must send a request's complete headers within this
KEEP_ALIVE_S = 5  # an idle keep-alive connection is closed after this
MAX_CONNECTIONS = 256  # concurrent connections; a request beyond gets a JSON 503 (serve/server.py)
EVICT_RESERVE = 16  # from MAX_CONNECTIONS - this on, a new connection refuses the oldest still without a request ...
REFUSED_LINGER_S = 2.0  # ... with a 503 sent at once, and closes it this much later (a reset would lose the 503) ...
MAX_LINGERING = 512  # ... while fewer than this many refused connections linger (a flood: closed at once); 500 clients
# connecting at once make about 260 (at 256, a few were closed at once and read a reset); with MAX_CONNECTIONS under
# the usual limit of 1,024 open files
MAX_HEADER_BYTES = 16 * 1024  # request line and headers (h11)
GRACEFUL_SHUTDOWN_S = 5  # after SIGTERM, requests in flight get this long before the worker is stopped
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")  # Host header names accepted by default (DNS rebinding)
CLIENT_HEADER = "x-smf-client"  # a request with this header (or an octet-stream body) may POST a file

# generation requests: the limits of every door, stablemofusion/core/limits.py (checked in serve/checks.py)

# the most work one request may ask for (stablemofusion.core.limits.request_cost, step-seconds): a 120 s timeline of the
# shipped student at 1 step with footskate 'loop' (1,920, about 2.6 s on one thread) is admitted, the same at 6
# steps (2,520, 5.9 s) is refused with 422, so a light request never waits long behind a heavy one
MAX_REQUEST_COST = 2000.0
# the work waiting in each lane, in requests of the most work: past it a new request gets 503 with a Retry-After
# (health says "saturated"), so no request joins a queue it cannot get through in seconds; a server whose
# --max-request-cost is raised queues this many of its larger requests
QUEUED_REQUESTS = 4
MAX_QUEUED_COST = QUEUED_REQUESTS * MAX_REQUEST_COST
# requests of at most this much work (the shipped teacher's 10 steps over a 20 s motion) queue in a lane of their
# own: batches alternate between it and the heavy lane, and a batch holds at most MAX_REQUEST_COST of work, so a
# light request waits for at most one heavy batch, however many heavy ones are queued
LIGHT_COST = 300.0
RECENT_RESULTS = 8  # motions kept by their request, so that asking again in another format converts, not generates

# POST /v1/convert (serve/convert.py): a file shown by the viewer
MAX_CONVERT_SECONDS = MAX_SECONDS  # as long as the longest motion
MAX_CONVERT_FRAMES = 120 * 120  # frames of an uploaded BVH (120 s at 120 fps), checked before any is decoded ...
MAX_CONVERT_VALUES = 4_000_000  # ... and frames x channels (32 MB as float64)
MAX_HIERARCHY_BYTES = 256 * 1024  # a BVH's HIERARCHY section, checked before it is parsed
MAX_ABS_METRES = 1e4  # any joint position shown

# the worker process (serve/worker.py)
WORKER_START_TIMEOUT_S = 600.0  # loading and warming the model
WORKER_STOP_S = 2.0  # asked to stop, then terminated, then killed
WORKER_MAX_FAILED_STARTS = 3  # consecutive starts that die before ready: the worker is marked failed
WORKER_RESTART_DELAY_S = 0.5
WORKER_POLL_S = 0.1
WORKER_BEAT_S = 1.0  # a worker process marks that it lives this often (a thread of its own, busy or not) ...
WORKER_BEAT_TIMEOUT_S = 5.0  # ... and one whose mark is older than this is unresponsive (stopped, frozen): not
# ready at once, its call fails with 503, and it is killed and started again
WORKER_CALL_BASE_S = 30.0  # every worker call has a deadline: this much, plus ...
WORKER_CALL_PER_WORK_S = 0.02  # ... this per second of motion per sampling step it was asked for (a 120 s
# timeline at 50 steps: 150 s more); a call past its deadline fails with 503 and the worker is started again
WARM_STEPS = 2  # the warm-up generation before the worker reports ready

# live streams (WebSocket /v1/stream: serve/live.py)
MAX_STREAMS = 4  # live streams at once (`smf serve --max-streams`); one more is told so and closed
STREAM_AHEAD_S = 1.5  # windows are made until the frames made play this long ahead of play time (a slow window
# on a loaded CPU does not make frames late) ...
STREAM_SEND_LEAD_S = 0.4  # ... but frames are sent at most this far ahead of their play time: a new prompt cuts
# the frames not sent yet and the stream is made again from there (a new prompt shows after what was sent)
STREAM_SWITCH_FACTOR = 1.25  # a new prompt's frames start this many times the slowest of the stream's recent
STREAM_RECENT_WINDOWS = 5  # windows after the prompt came (at least STREAM_SEND_LEAD_S): they come in time
STREAM_JOIN_S = 0.6  # a stream with less than STREAM_AHEAD_S + this made ahead joins a worker call that starts
# (windows of several streams in one batch cost far less than one by one); AHEAD + JOIN + a window (54 frames)
# must stay within the frames a stream can be cut back (pipelines/stream.py STREAM_REWIND, 60: tested)
STREAM_MESSAGE_FRAMES = 2  # frames are sent when this many are due (10 messages a second at 20 fps), or more
STREAM_GATHER_S = 0.002  # the stream hub gathers the windows asked for within this into one worker call
MAX_STREAM_SECONDS = 1800.0  # a stream ends (with an error message) after this much motion
STREAM_START_TIMEOUT_S = 5.0  # the first prompt must arrive within this after connecting (the viewer sends it on open;
# a silent connection holds a stream slot no longer than this)
MAX_STREAM_MESSAGE_BYTES = 4096  # one client message (uvicorn's ws_max_size: larger ones close the socket)
MAX_STREAM_MESSAGES = 20  # client messages per STREAM_MESSAGE_WINDOW_S; more are answered with an error
STREAM_MESSAGE_WINDOW_S = 1.0
STREAM_DECIMALS = 4  # joint coordinates sent rounded to 0.1 mm
