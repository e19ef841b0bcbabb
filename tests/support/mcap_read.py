"""Read an MCAP recording with the third-party `mcap` reader (PyPI): list its
channels with their message counts, decode every message as JSON and check it
against its channel's JSON Schema. Used by tests/record.rs."""

import json
import sys

import jsonschema
from mcap.reader import make_reader


def main(path):
    counts = {}
    validators = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None, "the recording has a summary"
        for channel in summary.channels.values():
            schema = summary.schemas[channel.schema_id]
            assert channel.message_encoding == "json", channel
            assert schema.encoding == "jsonschema", schema.name
        total = 0
        for schema, channel, message in reader.iter_messages():
            check = validators.get(schema.id)
            if check is None:
                document = json.loads(schema.data)
                # The draft the schema names ($schema), as Foxglove reads it.
                check = jsonschema.validators.validator_for(document)(document)
                validators[schema.id] = check
            check.validate(json.loads(message.data))
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            total += 1
    for topic in sorted(counts):
        print(f"channel {topic} {counts[topic]}")
    print(f"decoded {total} messages, each valid against its schema")


if __name__ == "__main__":
    main(sys.argv[1])
