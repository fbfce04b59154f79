"""The node's SDO server: the ``canopen`` package's server with CiA 301's transfer rules.

``canopen.sdo.SdoServer`` serves a VAR object at any sub-index (as if it were
0), keeps a segmented transfer going after the client aborted it, accepts
segments when no transfer is in progress and checks a segmented download's
object only after its last segment.  :class:`SdoServer` checks every request
first and follows each transfer from initiate to its end:

- an initiate request for an object that does not exist aborts with
  0x06020000, for a sub-index it does not have (any sub-index but 0 of a VAR)
  0x06090011, an upload of a write-only object 0x06010001, a download to a
  read-only one 0x06010002 -- before any data moves;
- a segment request outside a transfer of its kind aborts with 0x05040001;
- a client's abort (or the server's own) ends the transfer: later segments are
  refused and a segmented download's data so far is dropped, never written;
- a new initiate request ends any transfer in progress (CiA 301: the server
  serves one transfer at a time).

Block download is not supported (abort 0x05040001); a block upload request is
answered with the normal upload protocol, as CiA 301 allows.
"""

from __future__ import annotations

from typing import Any

import canopen
from canopen.objectdictionary import ODVariable
from canopen.sdo.constants import (
    ABORT_INVALID_COMMAND_SPECIFIER,
    ABORT_NO_SUBINDEX,
    ABORT_NOT_IN_OD,
    ABORT_READ_WRITEONLY,
    ABORT_WRITE_READONLY,
    EXPEDITED,
    NO_MORE_DATA,
    REQUEST_ABORTED,
    REQUEST_BLOCK_UPLOAD,
    REQUEST_DOWNLOAD,
    REQUEST_SEGMENT_DOWNLOAD,
    REQUEST_SEGMENT_UPLOAD,
    REQUEST_UPLOAD,
    RESPONSE_ABORTED,
    RESPONSE_DOWNLOAD,
    RESPONSE_SEGMENT_DOWNLOAD,
    RESPONSE_SEGMENT_UPLOAD,
    RESPONSE_UPLOAD,
    SDO_STRUCT,
)

UPLOAD = "upload"
DOWNLOAD = "download"
SEGMENT_OF = {REQUEST_SEGMENT_UPLOAD: UPLOAD, REQUEST_SEGMENT_DOWNLOAD: DOWNLOAD}
"""The transfer each segment request belongs to."""


class SdoServer(canopen.sdo.SdoServer):
    """SDO server of ``node`` (a :class:`canopen.LocalNode`) that keeps CiA 301's rules.

    :attr:`transfer` is the segmented transfer in progress (``"upload"``,
    ``"download"``) or None.
    """

    def __init__(self, node: canopen.LocalNode) -> None:
        assert node.id is not None
        super().__init__(0x600 + node.id, 0x580 + node.id, node)
        self.transfer: str | None = None
        self._index = self._subindex = 0  # the multiplexer an abort names before any transfer
        self._request = bytes(8)

    def on_request(self, can_id: int, data: Any, timestamp: float) -> None:
        command = data[0]
        ccs = command & 0xE0
        self._request = bytes(data)
        if ccs == REQUEST_ABORTED:
            self.transfer = None
            self._buffer = None
            self.request_aborted(data)
            return
        if ccs in SEGMENT_OF:
            if self.transfer != SEGMENT_OF[ccs]:
                self.abort(ABORT_INVALID_COMMAND_SPECIFIER)
                return
        else:  # an initiate request: a new transfer, checked before any data moves
            self.transfer = None
            self._buffer = None
            _, self._index, self._subindex = SDO_STRUCT.unpack_from(data)
            code = self._access_error(ccs, self._index, self._subindex)
            if code:
                self.abort(code)
                return
        super().on_request(can_id, data, timestamp)

    def _access_error(self, ccs: int, index: int, subindex: int) -> int:
        """The abort code an initiate request for ``index:subindex`` gets, 0 if allowed."""
        if index not in self.od:
            return ABORT_NOT_IN_OD
        entry = self.od[index]
        if isinstance(entry, ODVariable):
            if subindex != 0:
                return ABORT_NO_SUBINDEX
        elif subindex not in entry:
            return ABORT_NO_SUBINDEX
        else:
            entry = entry[subindex]
        if ccs in (REQUEST_UPLOAD, REQUEST_BLOCK_UPLOAD) and not entry.readable:
            return ABORT_READ_WRITEONLY
        if ccs == REQUEST_DOWNLOAD and not entry.writable:
            return ABORT_WRITE_READONLY
        return 0

    def send_response(self, response: Any) -> None:
        """Send ``response`` and note whether it starts, continues or ends a transfer."""
        scs, request = response[0] & 0xE0, self._request
        if scs == RESPONSE_ABORTED:
            self.transfer = None
            self._buffer = None
        elif scs == RESPONSE_UPLOAD:
            self.transfer = None if response[0] & EXPEDITED else UPLOAD
        elif scs == RESPONSE_DOWNLOAD:
            self.transfer = None if request[0] & EXPEDITED else DOWNLOAD
        elif (scs == RESPONSE_SEGMENT_UPLOAD and response[0] & NO_MORE_DATA) or (
            scs == RESPONSE_SEGMENT_DOWNLOAD and request[0] & NO_MORE_DATA
        ):
            self.transfer = None
        super().send_response(response)
