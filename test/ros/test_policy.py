"""
The shipped SROS2 policy (config/mlx_tempcomp.policy.xml) against the nodes' real graph.

The policy must name every topic and service each node uses, and nothing
else: a node that gains a topic without its permission fails here. The nodes
run over DDS with the shipped config, and in namespaces of their own with the
configurations that turn on every optional name (several chips, a supply
monitor, the ADIS16130 and MPU-6000 services, a bag with a second temperature
and a supply voltage replayed at rate factor 0, a model with secondary and
supply terms, both rest hint topics). The union of their graphs, per node,
must equal the node's profile, resolved as sros2 resolves it for the node's
namespace (its permissions.xsl: ``/x`` absolute, ``~/x`` under the node's
name, else under the namespace).

The policy's structure is checked against the sros2 policy schema, format
0.2.0 (sros2/policy/schemas/policy.xsd), with the standard library.
"""

from pathlib import Path
import xml.etree.ElementTree as ElementTree

from mlx_tempcomp.recordings.bag import ImuRecord, SupplyVoltageRecord, TemperatureRecord
from mlx_tempcomp.recordings.bag_writer import RawBagWriter
import pytest
from rclpy.node import NodeNameNonExistentError
from ros_harness import write_params

ROOT = Path(__file__).resolve().parents[2]
POLICY = ROOT / 'config' / 'mlx_tempcomp.policy.xml'
SHIPPED = ROOT / 'config' / 'mlx_tempcomp.yaml'
TIMEOUT_S = 120.0
T2_TOPIC = '/board/temperature'
KINDS = ('publish', 'subscribe', 'reply', 'request')
# The schema: each element's children, in order, and its attributes (required, optional).
RULES = {'topics': ('topic', ('publish', 'subscribe')),
         'services': ('service', ('reply', 'request')),
         'actions': ('action', ('call', 'execute'))}


def check_structure(root) -> None:
    """Assert what policy.xsd (0.2.0) asks of the policy, element by element."""
    assert root.tag == 'policy' and root.attrib == {'version': '0.2.0'}, root.attrib
    assert [child.tag for child in root] == ['enclaves']
    enclaves = root[0]
    assert len(enclaves) >= 1 and all(e.tag == 'enclave' for e in enclaves)
    for enclave in enclaves:
        assert set(enclave.attrib) == {'path'} and enclave.attrib['path'].startswith('/')
        assert len(enclave) >= 1 and all(p.tag == 'profiles' for p in enclave)
        for profiles in enclave:
            tags = [p.tag for p in profiles]
            assert tags and tags[0] == 'profile' and \
                tags == ['profile'] * (len(tags) - tags[-1:].count('metadata')) + \
                tags[-1:] * (tags[-1] == 'metadata'), tags
            for profile in (p for p in profiles if p.tag == 'profile'):
                assert set(profile.attrib) == {'ns', 'node'}, profile.attrib
                for rule in profile:
                    assert rule.tag in RULES, rule.tag
                    child, qualifiers = RULES[rule.tag]
                    assert rule.attrib and set(rule.attrib) <= set(qualifiers), rule.attrib
                    assert set(rule.attrib.values()) <= {'ALLOW', 'DENY'}, rule.attrib
                    assert len(rule) >= 1 and all(e.tag == child and e.text and
                                                  e.text.strip() == e.text for e in rule)


def policy_profiles(root) -> dict:
    """Give {node: (ns, {kind: [name as written]})} of the ALLOW rules; one profile a node."""
    profiles = {}
    for profile in root.iter('profile'):
        node = profile.attrib['node']
        assert node not in profiles, f'two profiles for {node}'
        allowed = {kind: [] for kind in KINDS}
        for rule in profile:
            for kind, qualifier in rule.attrib.items():
                assert qualifier == 'ALLOW', f'{node}: only ALLOW rules expected'
                allowed[kind] += [e.text for e in rule]
        profiles[node] = (profile.attrib['ns'], allowed)
    return profiles


def resolve(name: str, ns: str, node: str) -> str:
    """Give the fully qualified name sros2 makes of a policy ``name`` (permissions.xsl)."""
    ns = ns if ns.endswith('/') else ns + '/'
    if name.startswith('/'):
        return name
    if name.startswith('~'):
        return ns + node + name[1:]
    return ns + name


def graph(probe_node, node: str, ns: str) -> dict:
    """Give {kind: set of fully qualified names} of a running node; {} before it is seen."""
    try:
        found = {'publish': probe_node.get_publisher_names_and_types_by_node(node, ns),
                 'subscribe': probe_node.get_subscriber_names_and_types_by_node(node, ns),
                 'reply': probe_node.get_service_names_and_types_by_node(node, ns),
                 'request': probe_node.get_client_names_and_types_by_node(node, ns)}
    except NodeNameNonExistentError:
        return {}
    return {kind: {name for name, _ in names} for kind, names in found.items()}


def write_bag(path) -> None:
    """Write a short bag with a second temperature and a supply voltage, as a real one may."""
    with RawBagWriter(path, 'sqlite3', extra_temperature_topics=(T2_TOPIC,)) as writer:
        for i in range(20):
            stamp = 1_700_000_000_000_000_000 + i * 10_000_000
            writer.write_temperature(stamp, TemperatureRecord(stamp, 'imu_link', 25.0, 0.0))
            writer.write_temperature(stamp, TemperatureRecord(stamp, 'board', 30.0, 0.0),
                                     topic=T2_TOPIC)
            writer.write_supply_voltage(stamp, SupplyVoltageRecord(stamp, 'board', 5.0))
            writer.write_imu(stamp, ImuRecord(stamp, 'imu_link', [0.0, 0.0, 0.001],
                                              [0.0] * 9, [0.0] * 3, [-1.0] + [0.0] * 8,
                                              [-1.0] + [0.0] * 8))


def configurations(bag) -> list:
    """Give (executable, namespace, parameters over the shipped config) of every run."""
    return [
        ('driver_node', '/', {}),
        ('driver_node', '/mlx_xyz', {'axes': ['x', 'y', 'z'], 'spi.chip_selects': [0, 1, 2],
                                     'simulation.supply_monitor_hz': 10.0}),
        ('driver_node', '/adis', {'device': 'adis16130'}),
        ('driver_node', '/mpu', {'device': 'mpu6000'}),
        ('driver_node', '/bag', {'source': 'bag', 'bag.path': str(bag),
                                 'bag.temperature_2_topic': T2_TOPIC, 'bag.rate_factor': 0.0,
                                 'bag.on_end': 'hold'}),
        ('compensation_node', '/', {}),
        ('compensation_node', '/eeprom_xyz', {'axes': ['x', 'y', 'z'],
                                              'bias_tracking.rest_hint_topic': 'odom'}),
        ('compensation_node', '/effects', {
            'model': 'effects', 'effects.bias.z': [0.0, 1e-4], 'effects.secondary.z': [1e-4],
            'effects.supply_voltage.z': [1e-3], 'bias_tracking.rest_hint_topic': 'cmd_vel',
            'bias_tracking.rest_hint_type': 'geometry_msgs/Twist'}),
    ]


def test_the_policy_has_the_sros2_schema_structure():
    root = ElementTree.parse(POLICY).getroot()
    check_structure(root)
    assert sorted(policy_profiles(root)) == ['compensation_node', 'driver_node']
    paths = [e.attrib['path'] for e in root.iter('enclave')]
    assert paths == ['/mlx_tempcomp/driver_node', '/mlx_tempcomp/compensation_node']


@pytest.mark.parametrize('broken, message', [
    ('<policy version="0.1.0"><enclaves/></policy>', 'version'),
    ('<policy version="0.2.0"><contexts/></policy>', 'enclaves'),
    ('<policy version="0.2.0"><enclaves><enclave path="/a"><profiles><profile ns="/" '
     'node="n"><topics publish="MAYBE"><topic>t</topic></topics></profile></profiles>'
     '</enclave></enclaves></policy>', 'ALLOW'),
    ('<policy version="0.2.0"><enclaves><enclave path="/a"><profiles><profile ns="/" '
     'node="n"><topics reply="ALLOW"><topic>t</topic></topics></profile></profiles>'
     '</enclave></enclaves></policy>', 'reply'),
    ('<policy version="0.2.0"><enclaves><enclave path="/a"><profiles><profile ns="/">'
     '</profile></profiles></enclave></enclaves></policy>', 'ns')])
def test_the_structure_check_refuses_what_the_schema_refuses(broken, message):
    with pytest.raises(AssertionError, match=message):
        check_structure(ElementTree.fromstring(broken))


@pytest.mark.parametrize('name, ns, node, expected', [
    ('/rosout', '/robot', 'driver_node', '/rosout'),
    ('~/get_parameters', '/', 'driver_node', '/driver_node/get_parameters'),
    ('~/get_parameters', '/robot', 'driver_node', '/robot/driver_node/get_parameters'),
    ('imu/data', '/', 'compensation_node', '/imu/data'),
    ('imu/data', '/robot/', 'compensation_node', '/robot/imu/data')])
def test_names_resolve_as_sros2_resolves_them(name, ns, node, expected):
    assert resolve(name, ns, node) == expected


@pytest.mark.ros
@pytest.mark.slow
def test_the_policy_names_exactly_what_the_nodes_use(launcher, probe, tmp_path):
    bag = tmp_path / 'bag'
    write_bag(bag)
    runs = configurations(bag)
    for index, (executable, ns, params) in enumerate(runs):
        overrides = write_params(tmp_path / f'overrides_{index}.yaml', '/**', {
            'recalibration.state_file': str(tmp_path / f'zro_{index}.yaml'), **params})
        launcher.start(executable, '/**', None, label=f'{executable}_{index}', extra_args=[
            '--params-file', str(SHIPPED), '--params-file', overrides, '-r', f'__ns:={ns}'])
    profiles = policy_profiles(ElementTree.parse(POLICY).getroot())
    expected = {node: {kind: {resolve(name, '/', node) for name in names}
                       for kind, names in allowed.items()}
                for node, (_, allowed) in profiles.items()}

    def observed() -> dict:
        """Per node, the union over its runs, each name taken back to the namespace /."""
        union = {node: {kind: set() for kind in KINDS} for node in profiles}
        for executable, ns, _ in runs:
            found = graph(probe.node, executable, ns)
            if not found:
                return None
            for kind, names in found.items():
                # A name the profile allows in this namespace counts as its '/' form; any
                # other stays as it is, and fails the comparison below.
                to_root = {resolve(n, ns, executable): resolve(n, '/', executable)
                           for n in profiles[executable][1][kind]}
                union[executable][kind] |= {to_root.get(name, name) for name in names}
        return union

    # Discovery fills the graph in over time: wait until it matches, or fail with the
    # difference once the time is up.
    state = {}

    def matches() -> bool:
        state['observed'] = observed()
        return state['observed'] == expected

    try:
        probe.spin_until(matches, TIMEOUT_S, 'the graph to match the policy')
    except AssertionError:
        seen = state.get('observed')
        if seen is None:
            raise AssertionError('not every node was discovered\n' + launcher.logs()) from None
        differences = {f'{node} {kind}': {'not in the policy': sorted(
            seen[node][kind] - expected[node][kind]), 'unused': sorted(
            expected[node][kind] - seen[node][kind])} for node in expected for kind in KINDS
            if seen[node][kind] != expected[node][kind]}
        raise AssertionError(f'graph and policy differ: {differences}\n'
                             + launcher.logs()) from None
    # Every run is up: none refused its parameters (the optional names would be missing).
    assert all(process.running() for process in launcher.processes), launcher.logs()
