"""MCAP files (https://mcap.dev/spec): a reader that checks every CRC, a streaming writer, and
whole-file rewrite and recovery. What other code uses is exported here.

One job per module:

- ``reader``: the reader's public face: ``scan_mcap`` (pass 1) gives an ``McapFile`` whose
  ``chunks()`` walk yields each chunk's messages (pass 2); ``read_mcap`` reads a whole file into
  an ``McapContents``.
- ``scan``: pass 1, the structure: every record's framing and every CRC but the chunks', and
  the summary checked against the data section.
- ``resync``: after damage, the next chunk whose framing holds and whose CRC checks.
- ``chunks``: where a chunk lies (``ChunkRef``) and its records inflated (capped, CRC-checked),
  a few ahead on one pool thread.
- ``extract``: a chunk's inflated records into per-channel numpy arrays (``ChannelData``).
- ``chunk_kernel``: the message-index check compiled by numba; imported only by
  ``McapFile.chunks(compiled=True)`` and the Allan analysis, never from here.
- ``mapping``: the read-only memory map: opening, CRC over a range, releasing pages.
- ``records``: the byte layouts of the records, framing, record parsing, bounded decompression.
- ``writer``: ``BulkMcapWriter``, the streaming writer of chunked, indexed files.
- ``tools``: whole files: ``rewrite`` what was read, ``recover`` the readable part of a damaged
  file.

Importing this package imports neither numba nor any compiled kernel.
"""

from .reader import ChannelData, ChunkMessages, ChunkRef, McapContents, McapFile, Unverified, read_mcap, scan_mcap
from .records import COMPRESSIONS, MCAP_MAGIC, DecompressionError, import_hint
from .tools import recover, rewrite
from .writer import BulkMcapWriter

__all__ = [
    "COMPRESSIONS",
    "MCAP_MAGIC",
    "BulkMcapWriter",
    "ChannelData",
    "ChunkMessages",
    "ChunkRef",
    "DecompressionError",
    "McapContents",
    "McapFile",
    "Unverified",
    "import_hint",
    "read_mcap",
    "recover",
    "rewrite",
    "scan_mcap",
]
