"""Field sensors on MQTT: the sensor table, payload readers and the bridge's pure core
(:mod:`bintrack.mqtt.bridge_core`), Zigbee2MQTT playback of a dataset, and the broker options."""
