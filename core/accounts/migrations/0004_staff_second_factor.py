"""Staff tokens carry whether they were minted with the second factor; a staff account's
first factor needs another admin's leave; TOTP secrets and recovery seeds are encrypted.

Tokens made before are taken as minted without it: a staff account makes a new one from a
session that passed its second factor. The secrets are encrypted by the adapter the portal
reads them with (``core.accounts.adapter.MfaAdapter``); a value already encrypted is left.
"""

from cryptography.fernet import InvalidToken
from django.db import migrations, models

from core import crypto
from core.accounts.adapter import MFA_SECRETS_PURPOSE

# Where allauth keeps each kind's secret in ``Authenticator.data``.
SECRET_FIELDS = {"totp": "secret", "recovery_codes": "seed"}


def _is_encrypted(value: str) -> bool:
    try:
        crypto.cipher(MFA_SECRETS_PURPOSE).decrypt(value.encode("ascii"))
    except (InvalidToken, UnicodeEncodeError):
        return False
    return True


def encrypt_secrets(apps, schema_editor):
    Authenticator = apps.get_model("mfa", "Authenticator")
    for authenticator in Authenticator.objects.filter(type__in=SECRET_FIELDS).iterator():
        field = SECRET_FIELDS[authenticator.type]
        value = authenticator.data.get(field)
        if not isinstance(value, str) or _is_encrypted(value):
            continue
        authenticator.data[field] = crypto.encrypt(value, purpose=MFA_SECRETS_PURPOSE)
        authenticator.save(update_fields=["data"])


def decrypt_secrets(apps, schema_editor):
    Authenticator = apps.get_model("mfa", "Authenticator")
    for authenticator in Authenticator.objects.filter(type__in=SECRET_FIELDS).iterator():
        field = SECRET_FIELDS[authenticator.type]
        value = authenticator.data.get(field)
        if isinstance(value, str) and _is_encrypted(value):
            authenticator.data[field] = crypto.decrypt(value, purpose=MFA_SECRETS_PURPOSE)
            authenticator.save(update_fields=["data"])


class Migration(migrations.Migration):
    dependencies = [
        ("accounts", "0003_api_tokens_from_authtoken"),
        ("mfa", "0003_authenticator_type_uniq"),
    ]

    operations = [
        migrations.AddField(
            model_name="apitoken",
            name="mfa_verified",
            field=models.BooleanField(db_default=False, default=False),
        ),
        migrations.AddField(
            model_name="user",
            name="mfa_enrolment_allowed",
            field=models.BooleanField(
                db_default=False,
                default=False,
                help_text="A staff account may set up its first second factor (cleared once it has).",
            ),
        ),
        migrations.RunPython(encrypt_secrets, decrypt_secrets),
    ]
