"""The three micro-ROS with FIWARE use cases as data: where they happen
(``sites``), their enumerations (``enums``), and seeded simulators of the
Bosch lawnmower, the PIAP smart warehouse and the eProsima drone
(``registry.SIMULATORS``) that produce entity updates as the ROS 2 IoT Agent
reports them (``ros``, ``orion``). Used by the demo, the dashboards and the
explorer."""
