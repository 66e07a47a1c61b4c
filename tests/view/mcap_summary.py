"""An independent MCAP reader for tests/it/view.rs: opens a recording with the
`mcap` package (the reference Python implementation, not the writer isochron
uses), reads every message and prints one JSON object: the channels with their
schema name and encoding, message encoding, message count and bytes (message
data, uncompressed), and whether the file
has a summary section (written only when the recorder closed the file cleanly).

usage: python3 mcap_summary.py FILE.mcap
"""

import json
import sys

from mcap.reader import make_reader


def main() -> int:
    path = sys.argv[1]
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        counts = {}
        first_bytes = {}
        data_bytes = {}
        for schema, channel, message in reader.iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            data_bytes[channel.topic] = data_bytes.get(channel.topic, 0) + len(message.data)
            first_bytes.setdefault(channel.topic, len(message.data))
        channels = []
        if summary is not None:
            for cid, ch in sorted(summary.channels.items()):
                schema = summary.schemas.get(ch.schema_id)
                channels.append(
                    {
                        "topic": ch.topic,
                        "schema": schema.name if schema else None,
                        "schema_encoding": schema.encoding if schema else None,
                        "message_encoding": ch.message_encoding,
                        "count": counts.get(ch.topic, 0),
                        "first_message_bytes": first_bytes.get(ch.topic),
                        "bytes": data_bytes.get(ch.topic, 0),
                    }
                )
        stats = summary.statistics if summary is not None else None
        print(
            json.dumps(
                {
                    "has_summary": summary is not None,
                    "chunks": len(summary.chunk_indexes) if summary is not None else 0,
                    "compression": sorted(
                        {c.compression for c in summary.chunk_indexes}
                    )
                    if summary is not None
                    else [],
                    "message_count": stats.message_count if stats else None,
                    "messages_read": sum(counts.values()),
                    "channels": channels,
                }
            )
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
