"""The plant side: the gauge on the plant's MQTT broker, as an OPC UA server, and its
measurements as a Q-DAS AQDEF transfer file."""
