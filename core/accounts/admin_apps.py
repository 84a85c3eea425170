"""Django's admin app with the staff site (``core.accounts.admin_site``): named here, in a
module that imports no models, because the app is loaded before they are."""

from django.contrib.admin.apps import AdminConfig


class StaffAdminConfig(AdminConfig):
    default_site = "core.accounts.admin_site.StaffAdminSite"
