"""Read an MCAP recording the ordinary way with the third-party `mcap` reader (PyPI):
`make_reader(f).iter_messages()` on the open file, as its documentation shows, or with
`nonseeking` its NonSeekingReader in file order (`iter_messages(log_time_order=False)`:
in log time order it sorts every message first, and yields none from a file whose
end it cannot read).
Prints one JSON object: whether the file has a summary, its chunk indexes, the
messages per channel; on any exception, its type and text. Used by tests/record.rs.

usage: mcap_ordinary.py FILE [nonseeking]
"""

import json
import sys

from mcap.reader import NonSeekingReader, make_reader


def main(path, how):
    out = {"how": how, "counts": {}, "messages": 0}
    try:
        with open(path, "rb") as f:
            reader = NonSeekingReader(f) if how == "nonseeking" else make_reader(f)
            if how != "nonseeking":
                summary = reader.get_summary()
                out["summary"] = summary is not None
                out["chunk_indexes"] = len(summary.chunk_indexes) if summary else 0
            messages = (
                reader.iter_messages(log_time_order=False)
                if how == "nonseeking"
                else reader.iter_messages()
            )
            for _schema, channel, _message in messages:
                out["counts"][channel.topic] = out["counts"].get(channel.topic, 0) + 1
                out["messages"] += 1
    except Exception as e:  # what a user of the reader would see
        out["error"] = f"{type(e).__name__}: {e}"
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2] if len(sys.argv) > 2 else "make_reader")
