"""The OPC UA side of ``inspector serve``: the asyncua server with its endpoints, security and
users (:func:`secured_server`), and the information model of
:mod:`inspector_frontends.opcua.model` built in its address space (:func:`add_model`), each
variable's values written as :func:`data_value`. What the nodes do is
:class:`~inspector_frontends.opcua.server.InspectorServer`'s.
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import UTC
from pathlib import Path
from typing import Any

from asyncua import Server, ua

from inspector_frontends.opcua import model
from inspector_frontends.opcua.config import Credentials, ServerSettings
from inspector_frontends.opcua.security import SERVER_URI, Rules, UserManager, check_logins_off_the_loop, validator

__all__ = ["VARIANT_TYPES", "POLICIES", "secured_server", "add_model", "data_value"]

#: The variant type of each of the model's types.
VARIANT_TYPES = {"String": ua.VariantType.String, "Boolean": ua.VariantType.Boolean, "UInt32": ua.VariantType.UInt32,
                 "Int32": ua.VariantType.Int32, "Double": ua.VariantType.Double, "String[]": ua.VariantType.String}
#: The security policies of each ``security`` setting.
POLICIES = {
    "sign-encrypt": [ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt],
    "both": [ua.SecurityPolicyType.NoSecurity, ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt],
    "none": [ua.SecurityPolicyType.NoSecurity],
}


async def secured_server(settings: ServerSettings, creds: Credentials | None, pki: tuple[Path, Path, Path] | None,
                         log: Callable[[str], None]) -> Server:
    """An asyncua server for ``settings`` (initialised, not listening yet): its users (anonymous,
    and ``creds``' user, passwords checked off the event loop), endpoint and name, security
    policies and permission rules, identity tokens and, with ``pki`` (certificate, key, trusted
    clients' folder), its certificate and the clients' certificate check."""
    users = UserManager(creds, log)
    server = Server(user_manager=users)
    await server.init()
    check_logins_off_the_loop(server.iserver, users)  # PBKDF2 in a worker thread: reads go on
    server.set_endpoint(settings.endpoint)
    server.set_server_name("Inspector")
    await server.set_application_uri(SERVER_URI)
    server.set_security_policy(POLICIES[settings.security], permission_ruleset=Rules(settings.anonymous_write))
    tokens: list[type] = [ua.AnonymousIdentityToken]
    if creds is not None:
        tokens.append(ua.UserNameIdentityToken)
    server.set_identity_tokens(tokens)
    if pki is not None:
        cert, key, trusted = pki
        await server.load_certificate(str(cert))
        await server.load_private_key(str(key))
        server.set_certificate_validator(await validator(trusted))
    return server


async def add_model(server: Server, recipe_name: str, recipe_names: list[str],
                    handlers: dict[str, Callable[..., Any]]) -> tuple[int, dict[str, Any], dict[Any, str]]:
    """The information model under ``Objects/Inspector``: its variables (``RecipeName`` and
    ``Recipes`` starting as ``recipe_name`` and ``recipe_names``; the inputs writable) and its
    methods (``handlers``: a method's name -> its coroutine). Returns the namespace's index, the
    node of each variable by name and the name of each input by node id."""
    idx = await server.register_namespace(model.NAMESPACE)
    nodes: dict[str, Any] = {}
    inputs: dict[Any, str] = {}
    obj = await server.nodes.objects.add_object(ua.NodeId(ua.String(model.OBJECT), ua.Int16(idx)),
                                                ua.QualifiedName(model.OBJECT, idx))
    for v in model.VARIABLES:
        initial = v.initial
        if v.name == "RecipeName":
            initial = recipe_name
        elif v.name == "Recipes":
            initial = recipe_names
        node = await obj.add_variable(ua.NodeId(ua.String(model.node_id(v.name)), ua.Int16(idx)),
                                      ua.QualifiedName(v.name, idx), ua.Variant(initial, VARIANT_TYPES[v.type]))
        await node.write_attribute(ua.AttributeIds.Description, ua.DataValue(ua.Variant(ua.LocalizedText(v.doc))))
        if v.access == "rw":
            await node.set_writable()
            inputs[node.nodeid] = v.name
        nodes[v.name] = node
    for m in model.METHODS:
        args = [ua.Argument(Name=n, DataType=ua.NodeId(ua.Int32(VARIANT_TYPES[t].value)), ValueRank=-1,
                            Description=ua.LocalizedText(d)) for n, t, d in m.inputs]
        node = await obj.add_method(ua.NodeId(ua.String(model.node_id(m.name)), ua.Int16(idx)),
                                    ua.QualifiedName(m.name, idx), handlers[m.name], args, [])
        await node.write_attribute(ua.AttributeIds.Description, ua.DataValue(ua.Variant(ua.LocalizedText(m.doc))))
    return idx, nodes, inputs


def data_value(name: str, value: Any) -> ua.DataValue:
    """``value`` as variable ``name``'s new value (its variant type), time-stamped now at the
    source and the server."""
    v = model.variable(name)
    now = ua.DateTime.now(UTC)
    return ua.DataValue(ua.Variant(value, VARIANT_TYPES[v.type]), SourceTimestamp=now, ServerTimestamp=now)
